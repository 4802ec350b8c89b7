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

The analysis works on the Jacobian with unit-norm columns (so mm and rad columns compare), takes
its singular values for rank and condition number, and chooses a base parameter set by QR with
column pivoting. Anchor parameters (P0, c) and then the tool point are taken first, since they
must be estimated anyway; DH parameters fill the remaining rank in pivot order. Each parameter
left out gets a reason: a known structural cause, the kept parameters it is a combination of,
and whether it would be identifiable with well-spread poses (``structural_jacobian``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg

from calib.cable import N_DH, N_KIN
from calib.kinematics import FloatArray


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
    norms = np.linalg.norm(jac, axis=0)
    safe = np.where(norms > 0, norms, 1.0)
    return jac / safe, norms


def _condition(jac_unit: FloatArray) -> tuple[FloatArray, float]:
    if jac_unit.shape[1] == 0:
        return np.zeros(0), 1.0
    s = np.asarray(np.linalg.svd(jac_unit, compute_uv=False), dtype=np.float64)
    cond = float(s[0] / s[-1]) if s[-1] > 0 else float("inf")
    return s, cond


def _base_set(jac_unit: FloatArray, forced: list[int], rest: list[int], rtol: float) -> list[int]:
    """Columns of a base set: independent ``forced`` columns first, then pivoted QR on the rest."""
    chosen: list[int] = []
    if forced:
        _, r, piv = scipy.linalg.qr(jac_unit[:, forced], mode="economic", pivoting=True)
        diag = np.abs(np.diag(r))
        keep = diag > rtol * max(diag[0], 1e-300) if diag.size else np.zeros(0, dtype=bool)
        chosen = [forced[i] for i in piv[: int(np.count_nonzero(keep))]]
    if not rest:
        return sorted(chosen)
    sub = jac_unit[:, rest]
    if chosen:
        q_forced, _ = np.linalg.qr(jac_unit[:, chosen])
        sub = sub - q_forced @ (q_forced.T @ sub)
    _, r, piv = scipy.linalg.qr(sub, mode="economic", pivoting=True)
    diag = np.abs(np.diag(r))
    # Relative to a unit column: a residual below rtol means "inside the span already".
    n_keep = int(np.count_nonzero(diag > rtol))
    chosen += [rest[i] for i in piv[:n_keep]]
    return sorted(chosen)


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
    _, cond_base = _condition(jac_unit[:, base])
    tool_free = all(candidates[i] for i in tool_idx) and all(i in base for i in tool_idx)

    generic_ok: set[int] = set()
    if structural_jacobian is not None:
        g_unit, g_norms = _unit_columns(structural_jacobian)
        g_rest = [i for i in idx if i < N_DH and g_norms[i] > 0]
        generic_ok = set(_base_set(g_unit, forced, g_rest, rtol))

    reasons: dict[str, str] = {}
    unident = [i for i in idx if i not in base]
    for i in unident:
        name = names[i]
        known = _structural_reason(name, tool_free)
        if norms[i] == 0:
            reasons[name] = "does not change the cable length at these poses"
            continue
        coef, *_ = np.linalg.lstsq(jac_unit[:, base], jac_unit[:, i], rcond=None)
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
