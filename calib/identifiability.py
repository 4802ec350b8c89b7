"""Which parameters can cable-length data determine, and why not the others.

Distance-only data cannot see everything:

- ``theta1`` and ``d1``: a rotation about and a translation along the base z axis move the
  robot rigidly relative to the anchor; the anchor position ``P0`` absorbs them.
- With the tool point identified, the four joint-6 parameters only move the hook point inside
  the flange frame: the tool point absorbs them (and ``alpha6`` does not move a point on the
  flange axis at all).
- Parallel consecutive joint axes (JR680: joints 2 and 3, ``alpha2 = 0``) make translations
  along them redundant (``d2`` vs ``d3``).
- Local data (the real HSR set covers a few degrees per joint) make further combinations
  numerically invisible: the scaled Jacobian's condition number reaches 1e7–1e10.

The analysis works on the Jacobian with unit-norm columns (so mm and rad columns compare),
reduced to its triangular QR factor (same inner products, ``p × p`` whatever the number of
samples). It takes the singular values for rank and condition number, and chooses a base
parameter set by greedy column pivoting: the pivot order of QR with column pivoting, but ties
go to the earlier parameter, so that exactly redundant pairs such as d2/d3 resolve the same way
every time. Anchor parameters (P0, c) and then the tool point are taken first, since they must
be estimated anyway; DH parameters fill the remaining rank in pivot order. Each parameter
left out gets a reason: a known structural cause, the kept parameters it is a combination of,
and whether it would be identifiable with well-spread poses (``structural_jacobian``).

Before any data are fitted, :func:`max_solved` counts the parameters identify can solve at
most for a robot, its anchors and the ``fix``/``free`` names (the base set at well-spread
generic poses): :func:`calib.options.validate` needs more training rows than that.

**Noise-level threshold** (``noise_mm`` and ``plausible``). ``rtol`` only removes what is
redundant to rounding. A DH parameter can pass it and still be worth fixing: with the hook
point near the flange axis, ``d5`` and ``theta5`` are nearly redundant with the tool point and
each other, and their least-squares 1σ on a few dozen good poses at low noise is several times
a plausible manufacturing error (docs/planning.md; ``a5``/``alpha5`` go with them). Fixing a
parameter at nominal costs a bias of the order of its true error, of which the other
parameters absorb all but the part outside their span; solving for it costs its standard deviation
``σ_i = noise · sqrt([(JᵀJ)⁻¹]_ii)``. So, given the length noise and a plausible error size
``δ_i`` per parameter, DH parameters are dropped one at a time, worst ``σ_i/δ_i`` first, until
every remaining one has ``σ_i ≤ δ_i``. In terms of the scaled Jacobian ``J_i δ_i`` this is a
relative threshold on each column's component outside the span of the others: it must exceed
``noise`` (mm of length over the whole data set), i.e. the parameter's plausible error must
leave a trace in the data above one noise σ. The anchors and the tool point are never dropped.
"""

from __future__ import annotations

import threading
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, replace
from typing import cast

import numpy as np

from calib.cable import N_DH, N_KIN, ParamLayout, length_jacobian
from calib.kinematics import N_JOINTS, FloatArray
from calib.models import POSE_CLIP_DEG, RobotModel


@dataclass
class Identifiability:
    """Result of :func:`analyse`.

    Attributes
    ----------
    rank : int
        Numerical rank of the scaled Jacobian of the candidate parameters.
    condition_number : float
        ``σ_max/σ_min`` of the scaled Jacobian of all candidates (inf if rank-deficient).
    condition_number_base : float
        The same for the base set only.
    base : list of str
        Parameters solved for (identifiable), in layout order.
    unidentifiable : list of str
    reasons : dict of str to str
        Why each unidentifiable parameter is left out.
    singular_values : list of float
        Of the scaled candidate Jacobian, descending, relative to the largest.
    """

    rank: int
    condition_number: float
    condition_number_base: float
    base: list[str]
    unidentifiable: list[str]
    reasons: dict[str, str] = field(default_factory=dict)
    singular_values: list[float] = field(default_factory=list)
    rtol: float = 1e-8

    def to_dict(self) -> dict[str, object]:
        def finite(v: float) -> float | None:
            return float(v) if np.isfinite(v) else None

        return {
            "rank": self.rank,
            "condition_number": finite(self.condition_number),
            "condition_number_base": finite(self.condition_number_base),
            "rtol": self.rtol,
            "identifiable": list(self.base),
            "unidentifiable": list(self.unidentifiable),
            "reasons": dict(self.reasons),
        }


def _unit_columns(jac: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Unit-norm columns, compressed to at most ``p`` rows, and the column norms ``(p,)``.

    Everything the analysis computes (singular values, pivoted QR, least-squares coefficients
    between columns) depends only on the columns' inner products, which the triangular factor
    ``R`` of ``J = Q R`` preserves. Working on ``R`` (``p × p``) instead of ``J`` (``n × p``) makes
    the analysis independent of ``n``.
    """
    norms = np.linalg.norm(jac, axis=0)
    safe = np.where(norms > 0, norms, 1.0)
    unit = jac / safe
    if unit.shape[0] > unit.shape[1]:
        unit = cast(FloatArray, np.linalg.qr(unit, mode="r"))  # R only; stubs say QRResult
    return unit, norms


def _condition(jac_unit: FloatArray) -> tuple[FloatArray, float]:
    if jac_unit.shape[1] == 0:
        return np.zeros(0), 1.0
    s = np.asarray(np.linalg.svd(jac_unit, compute_uv=False), dtype=np.float64)
    cond = float(s[0] / s[-1]) if s[-1] > 0 else float("inf")
    return s, cond


#: Two candidate columns whose components outside the chosen span differ by less than this
#: (relative) are a tie; the one earlier in the layout wins.
TIE_RTOL = 1e-6


def _greedy_pivot(cols: FloatArray, candidates: list[int], threshold: float) -> list[int]:
    """Columns chosen one by one by the largest component outside the span of those chosen.

    This is the pivot order of QR with column pivoting, except that ties (exactly redundant
    columns such as ``d2``/``d3`` on parallel axes have equal residual norms) go to the lowest
    index instead of to rounding noise, so the base set does not depend on how the Jacobian
    was computed or compressed. Stops when the largest remaining component is ``≤ threshold``.
    Returns indices into ``candidates`` order, as chosen.
    """
    work = np.array(cols[:, candidates], dtype=float)
    free = np.ones(len(candidates), dtype=bool)
    chosen: list[int] = []
    while free.any():
        norms = np.sqrt(np.einsum("ij,ij->j", work, work))
        best = float(norms[free].max())
        if best <= threshold:
            break
        pick = int(np.flatnonzero(free & (norms >= best * (1.0 - TIE_RTOL)))[0])
        q = work[:, pick] / norms[pick]
        for _ in range(2):  # Gram–Schmidt twice: orthogonal to rounding
            work -= q[:, None] * (q @ work)
        chosen.append(pick)
        free[pick] = False
    return [candidates[i] for i in chosen]


def _base_set(jac_unit: FloatArray, forced: list[int], rest: list[int], rtol: float) -> list[int]:
    """Columns of a base set: independent ``forced`` columns first, then the rest.

    ``forced`` columns count as independent when their component outside the span of those
    already chosen exceeds ``rtol`` times the largest forced column norm; the other columns
    when it exceeds ``rtol`` (columns have unit norm).
    """
    chosen: list[int] = []
    if forced:
        top = float(np.linalg.norm(jac_unit[:, forced], axis=0).max())
        chosen = _greedy_pivot(jac_unit, forced, rtol * max(top, 1e-300))
    if not rest:
        return sorted(chosen)
    sub = jac_unit
    if chosen:
        q_forced, _ = np.linalg.qr(jac_unit[:, chosen])
        sub = jac_unit - q_forced @ (q_forced.T @ jac_unit)
    # Relative to a unit column: a residual below rtol means "inside the span already".
    chosen += _greedy_pivot(sub, rest, rtol)
    return sorted(chosen)


def _noise_limited(
    jac_unit: FloatArray,
    norms: FloatArray,
    base: list[int],
    noise_mm: float,
    plausible: FloatArray,
) -> tuple[list[int], dict[int, tuple[float, float]]]:
    """Drop DH columns of ``base`` whose predicted 1σ exceeds their plausible error.

    ``jac_unit`` (r, p) unit columns, ``norms`` (p,) their original norms, ``plausible`` (p,)
    the plausible error per parameter (internal units; ``inf`` never drops). Returns the kept
    base and, per dropped column, ``(σ, δ)`` in internal units.
    """
    base = list(base)
    dropped: dict[int, tuple[float, float]] = {}
    while base:
        u = jac_unit[:, base]
        evals, evecs = np.linalg.eigh(u.T @ u)
        if evals[0] <= 0:
            break  # rank-deficient: left to rtol
        inv_diag = np.einsum("ij,j,ij->i", evecs, 1.0 / evals, evecs)
        sigma = noise_mm * np.sqrt(inv_diag) / norms[base]
        ratio = np.where(np.array(base) < N_DH, sigma / plausible[base], 0.0)
        worst = int(np.argmax(ratio))
        if ratio[worst] <= 1.0:
            break
        dropped[base[worst]] = (float(sigma[worst]), float(plausible[base[worst]]))
        del base[worst]
    return base, dropped


def _structural_reason(name: str, tool_free: bool) -> str | None:
    if name == "theta1":
        return "rotation about the base z axis: absorbed by the anchor position P0"
    if name == "d1":
        return "translation along the base z axis: absorbed by the anchor position P0"
    if tool_free and name in ("alpha6", "a6", "d6", "theta6"):
        return "moves the hook point within the flange frame: absorbed by the tool point"
    return None


def analyse(
    jac: FloatArray,
    names: list[str] | tuple[str, ...],
    candidates: FloatArray,
    *,
    rtol: float = 1e-8,
    structural_jacobian: FloatArray | None = None,
    noise_mm: float | None = None,
    plausible: FloatArray | None = None,
) -> Identifiability:
    """Rank, conditioning and base set of the candidate parameters.

    Parameters
    ----------
    jac : ndarray, shape (n, p)
        ``∂L/∂θ`` of all parameters at the current estimate (internal units).
    names : sequence of str, length p
    candidates : ndarray of bool, shape (p,)
        Parameters the user allows to be solved for (not fixed by name).
    rtol : float
        A scaled column is independent when its component outside the span of the columns
        already chosen exceeds ``rtol``; singular values below ``rtol · σ_max`` count as zero.
    structural_jacobian : ndarray, shape (m, p), optional
        The same Jacobian at well-spread generic poses; used to tell structural redundancy from
        a lack of excitation in these data.
    noise_mm : float, optional
        1σ length noise [mm]; with ``plausible``, DH parameters whose predicted 1σ exceeds
        their plausible error are left out too (the noise-level threshold of the module
        docstring). Default: rank by ``rtol`` only.
    plausible : ndarray, shape (p,), optional
        Plausible error size per parameter, internal units (mm, rad).
    """
    names = list(names)
    idx = [i for i in range(len(names)) if candidates[i]]
    jac_unit, norms = _unit_columns(jac)
    s, cond = _condition(jac_unit[:, idx])
    rank = int(np.count_nonzero(s > rtol * s[0])) if s.size else 0
    tool_idx = list(range(N_DH, N_KIN))
    forced = [i for i in idx if i >= N_KIN] + [i for i in idx if i in tool_idx]
    rest = [i for i in idx if i < N_DH and norms[i] > 0]
    base = _base_set(jac_unit, forced, rest, rtol)
    noisy: dict[int, tuple[float, float]] = {}
    if noise_mm is not None and plausible is not None:
        if jac.shape[1] != np.size(plausible):
            raise ValueError(
                f"plausible: {np.size(plausible)} values for {jac.shape[1]} parameters"
            )
        base, noisy = _noise_limited(jac_unit, norms, base, noise_mm, np.asarray(plausible))
    _, cond_base = _condition(jac_unit[:, base])
    tool_free = all(candidates[i] for i in tool_idx) and all(i in base for i in tool_idx)

    generic_ok: set[int] = set()
    if structural_jacobian is not None:
        g_unit, g_norms = _unit_columns(structural_jacobian)
        g_rest = [i for i in idx if i < N_DH and g_norms[i] > 0]
        generic_ok = set(_base_set(g_unit, forced, g_rest, rtol))

    reasons: dict[str, str] = {}
    unident = [i for i in idx if i not in base]
    # Each left-out column as a combination of the base columns (one solve for all of them).
    coefs = (
        np.linalg.lstsq(jac_unit[:, base], jac_unit[:, unident], rcond=None)[0]
        if unident and base
        else np.zeros((len(base), len(unident)))
    )
    for col, i in enumerate(unident):
        name = names[i]
        known = _structural_reason(name, tool_free)
        if norms[i] == 0:
            reasons[name] = "does not change the cable length at these poses"
            continue
        if i in noisy:
            sig, plaus = noisy[i]
            angle = name.startswith(("alpha", "theta"))
            f, unit = (180.0 / np.pi, "deg") if angle else (1.0, "mm")
            reasons[name] = (
                f"below the noise: predicted 1σ {sig * f:.3g} {unit} exceeds a "
                f"plausible error {plaus * f:.3g} {unit} at {noise_mm} mm noise; "
                f"fixed at nominal"
            )
            continue
        coef = coefs[:, col]
        order = np.argsort(-np.abs(coef))
        partners = [names[base[j]] for j in order[:4] if abs(coef[j]) > 0.1 * abs(coef[order[0]])]
        combo = f"linear combination of {', '.join(partners)}"
        if known is not None:
            reasons[name] = known
        elif structural_jacobian is not None and i in generic_ok:
            reasons[name] = f"not excited by these poses (local data): {combo}"
        else:
            reasons[name] = f"redundant (e.g. parallel joint axes): {combo}"
    return Identifiability(
        rank=rank,
        condition_number=cond,
        condition_number_base=cond_base,
        base=[names[i] for i in base],
        unidentifiable=[names[i] for i in unident],
        reasons=reasons,
        singular_values=[float(v / s[0]) for v in s] if s.size else [],
        rtol=rtol,
    )


# ------------------------------------------------------------------ what identify solves
#: Poses of :func:`generic_jacobian` and the seed that draws them.
GENERIC_POSES = 200
GENERIC_SEED = 20230410
#: The start :func:`max_solved` assumes where identify fits one from the data: a tool-point
#: error [mm] off the flange axis (a hook point on the axis hides ``alpha6``, ``d5``,
#: ``theta5``), and anchor positions [mm] off every axis (anchor ``k`` at
#: ``GENERIC_ANCHOR_MM + k * GENERIC_ANCHOR_STEP_MM``). Any such generic point gives the
#: largest rank, which a fitted start can only reach, never exceed.
GENERIC_TOOL_ERROR_MM = (37.0, -23.0, 61.0)
GENERIC_ANCHOR_MM = (1130.0, -457.0, 312.0)
GENERIC_ANCHOR_STEP_MM = (-611.0, 733.0, 97.0)


def generic_jacobian(model: RobotModel, layout: ParamLayout, theta: FloatArray) -> FloatArray:
    """``∂L/∂θ`` at :data:`GENERIC_POSES` fixed well-spread poses, shape (200, p), internal
    units: tells structural redundancy from a lack of excitation in the data.

    The poses are drawn uniformly within the joint limits (clipped to ±170 deg) with a fixed
    seed; the anchors take turns.
    """
    rng = np.random.default_rng(GENERIC_SEED)
    limits = model.limits_deg()
    lo = np.maximum(limits[:, 0], -POSE_CLIP_DEG)
    hi = np.minimum(limits[:, 1], POSE_CLIP_DEG)
    hi = np.where(hi > lo, hi, lo + 1.0)
    q = model.table_rad(rng.uniform(lo, hi, size=(GENERIC_POSES, N_JOINTS)))
    aidx = np.arange(GENERIC_POSES) % len(layout.anchors)
    _, jac = length_jacobian(model, theta, q, aidx)
    return jac


def candidate_mask(layout: ParamLayout, identify_tool: bool, fix: Iterable[str]) -> np.ndarray:
    """Parameters identify may solve, shape (p,) bool: all but the tool point (unless
    ``identify_tool``) and the names in ``fix``."""
    candidates = np.ones(layout.size, dtype=bool)
    if not identify_tool:
        candidates[N_DH:N_KIN] = False
    for name in fix:
        candidates[layout.index(name)] = False
    return candidates


def solved_mask(
    layout: ParamLayout, base: Sequence[str], candidates: np.ndarray, free: Iterable[str]
) -> np.ndarray:
    """The parameters identify solves, shape (p,) bool: the base set within the candidates,
    plus the names in ``free``."""
    solved = np.asarray(np.array([n in base for n in layout.names]) & candidates, dtype=bool)
    for name in free:
        solved[layout.index(name)] = True
    return solved


def max_solved(
    model: RobotModel,
    layout: ParamLayout,
    candidates: np.ndarray,
    free: Iterable[str],
    *,
    rtol: float = 1e-8,
) -> int:
    """The most parameters identify can solve for this robot, these anchors and options,
    before any data are seen.

    The base set at :func:`generic_jacobian`'s well-spread poses from a generic start
    (:data:`GENERIC_TOOL_ERROR_MM` when the tool point is solved, otherwise the nominal
    ``model.tool_mm``; anchors at :data:`GENERIC_ANCHOR_MM`), plus the names in ``free``.
    Data with little excitation can only lower the rank, so identify never solves more (up
    to a name in ``free`` that the data's base set would otherwise replace).

    Parameters
    ----------
    model : RobotModel
        Nominal model, with any tool override applied.
    layout : ParamLayout
    candidates : ndarray of bool, shape (p,)
        See :func:`candidate_mask`.
    free : iterable of str
        Parameter names solved even if unidentifiable.
    rtol : float
        As :func:`analyse`.

    The answer depends on these arguments only, so it is kept (the last
    :data:`MAX_SOLVED_CACHE` of them): :func:`calib.options.validate` asks before every
    identification.
    """
    free = tuple(free)
    limits = model.joint_limits_deg
    key = (
        model.convention,
        np.asarray(model.dh_table, dtype=float).tobytes(),
        None if limits is None else np.asarray(limits, dtype=float).tobytes(),
        np.asarray(model.tool_mm, dtype=float).tobytes(),
        model.controller,
        layout.anchors,
        np.asarray(candidates, dtype=bool).tobytes(),
        free,
        rtol,
    )
    with _max_solved_lock:
        known = _max_solved_cache.get(key)
    if known is not None:
        return known
    count = _max_solved(model, layout, candidates, free, rtol)
    with _max_solved_lock:
        if len(_max_solved_cache) >= MAX_SOLVED_CACHE:
            _max_solved_cache.pop(next(iter(_max_solved_cache)))  # the oldest
        _max_solved_cache[key] = count
    return count


#: Answers of :func:`max_solved` kept (the oldest goes first).
MAX_SOLVED_CACHE = 64
_max_solved_cache: dict[tuple[object, ...], int] = {}
_max_solved_lock = threading.Lock()


def _max_solved(
    model: RobotModel,
    layout: ParamLayout,
    candidates: np.ndarray,
    free: Iterable[str],
    rtol: float,
) -> int:
    theta = np.zeros(layout.size)
    if candidates[N_DH:N_KIN].any():
        theta[N_DH:N_KIN] = GENERIC_TOOL_ERROR_MM
    for k in range(len(layout.anchors)):
        p0 = np.add(GENERIC_ANCHOR_MM, np.multiply(k, GENERIC_ANCHOR_STEP_MM))
        theta[layout.anchor_slice(k)] = [*p0, 0.0]
    jac = generic_jacobian(model, layout, theta)
    ident = analyse(jac, layout.names, candidates, rtol=rtol)
    return int(np.count_nonzero(solved_mask(layout, ident.base, candidates, free)))


def with_tool(model: RobotModel, tool_mm: Sequence[float] | None) -> RobotModel:
    """``model`` with its nominal tool point replaced by ``tool_mm`` [mm] (None: as it is)."""
    if tool_mm is None:
        return model
    return replace(model, tool_mm=np.asarray(tool_mm, dtype=float))
