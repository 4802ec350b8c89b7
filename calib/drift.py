"""How the measurement changes over a campaign: steps and a smooth drift, as nuisance terms.

A real campaign is not stationary: the indicator's zero creeps with temperature and cable
creep, a sensor stand gets bumped, an operator re-zeroes the indicator. Left out of the model,
these changes are soaked up by the robot's parameters (an ML fit turns a drift into absurd
geometry) or inflate the residual. This module models them as *extra nuisance parameters* of
the least-squares problem, never folded into the robot's DH, tool or compensation::

    L_i = |p_tool(q_i; θ) − P0| + c + b(t_i)ᵀ β                                     [mm]

``b(t)`` (shape (m,)) is a basis of the change over capture time ``t`` and ``β`` (shape (m,))
its coefficients [mm]:

* **smooth drift of the offset**: piecewise-linear in time with ``K`` uniformly spaced knots
  (hat functions, the first dropped: the anchor's ``c`` is the level at the first knot), held
  constant outside the training span;
* **re-zero** at time ``t_k``: a new offset from then on, the column ``1[t ≥ t_k]``;
* **sensor moved** at ``t_k``: a new ``P0`` and offset, the columns ``1[t ≥ t_k]`` and
  ``−u_i 1[t ≥ t_k]`` (``u_i`` the unit vector from ``P0`` to the tool at the campaign's
  robot-model fit): the first-order change of ``|p − P0 − δ|`` for a shift ``δ`` of the anchor
  point. The neglected term is ``|δ⊥|² / (2 |p − P0|)``: 0.008 mm for a 4 mm bump at 1 m.

The basis does not depend on ``θ``, so the problem is separable: :class:`calib.problem.Problem`
projects the residual and Jacobian onto the complement of ``span(√w · B)`` (variable projection,
Golub and Pereyra), every solver sees the robot's parameters only, and ``β`` follows by linear
least squares at the end (:func:`calib.linalg.coefficients`).

**Choosing the model** (:func:`select`): at the plain (no-drift) fit, the linearised problem
``r ≈ J δx + B β`` (prior rows included, so that a change the MAP prior would not let the
geometry absorb is credited to the drift) gives each candidate's residual sum of squares in
closed form. The criterion is BIC, ``N log(RSS / N) + m' log N`` with ``m'`` the columns plus
one per change point (its location), and "none" is one of the candidates: clean data keep the
plain fit. Change points are found by binary segmentation: a scan of every split of the
training rows in time order for the one that removes the most residual (a likelihood-ratio
scan on the robot-model fit, all locations in one pass with cumulative sums), kept while it
lowers BIC, up to :data:`MAX_STEPS`. At each kept location the re-zero (1 column) and the
sensor move (4 columns) compete by BIC. The smooth drift's knot count is chosen from
:data:`KNOT_CHOICES` by BIC too. ``auto`` takes the lowest BIC of none, steps, smooth, and
steps on top of the chosen smooth drift.

**Where the issue and the paper are vague, and what is chosen here:**

* Time is the sample's ``t_s`` column (seconds) when present, else the row order; rates are
  reported in mm/h, or mm per 100 samples without time.
* The drift of ``P0`` itself (beyond steps) is not modelled: on the campaigns at hand the
  offset's drift explains the residual, and a smooth 3-D anchor drift is nearly collinear with
  the offset drift over a short capture.
* A change point can only be located between two *training* rows; it is reported at the first
  training row after it, and placed at the midpoint of the two rows' times (held-out rows in
  between are evaluated with the step on past the midpoint: a held-out row right at a step
  may be off by the step's size).
* Test rows get the drift interpolated at their own time; the train/test split is random over
  rows, so held-out times lie inside the training span. A smooth drift is separable from the
  geometry only if the pose order is not correlated with the geometry's sensitivities; the
  linearised criterion sees such a correlation (the projected basis shrinks) and answers
  "none" or fewer knots.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from calib.anchors import PLAIN_FIT
from calib.kinematics import FloatArray
from calib.linalg import orthonormal
from calib.options import DriftMode
from calib.problem import Problem
from calib.robust import median
from calib.solvers import geolm

StepKind = Literal["rezero", "sensor_moved"]

#: Knot counts (both ends included) the smooth drift may take; a count needs at least
#: :data:`ROWS_PER_KNOT` training rows per knot.
KNOT_CHOICES: tuple[int, ...] = (2, 3, 4, 5, 6, 8, 10, 12, 16, 20, 24, 32, 40, 48)
ROWS_PER_KNOT = 8
#: Most change points binary segmentation keeps.
MAX_STEPS = 6
#: Fewest training rows on either side of a change point.
MIN_SEGMENT_ROWS = 8
#: Fewest training rows on either side of a sensor move: locating a new P0 (4 unknowns) from
#: fewer poses is an extrapolation (a short segment of the HSR data "found" a move of
#: millimetres whose offset and P0 cancel, and the held-out error grew).
MIN_MOVE_ROWS = 30
#: Least share of the plain fit's residual sum of squares a model (and each of its steps, of
#: the residual left before it) must explain to be chosen over none by ``auto``: BIC assumes
#: independent errors, but unmodelled robot error (compliance, the robot's own warm-up) is
#: correlated along a pose sequence and passes BIC by a little. Below 10 % (the RMS 5 %
#: lower) a change is not worth a model; the real changes of bench/drift.md's campaigns
#: explain far more.
MIN_GAIN = 0.1
#: Rows beyond this many robust σ of the residual a chosen model leaves are gross outliers:
#: the choice is made again without them.
GROSS_SIGMA = 6.0
#: Fewest training rows to model a drift at all: with fewer, a drift cannot be told from the
#: robot's geometry and the outliers (the 120-pose sets of issue 19 train on 96 rows).
MIN_ROWS = 60


@dataclass(frozen=True)
class Step:
    """A change point at time ``t`` (midway between two training rows; the first training
    row after it: ``row``, 0-based in the samples) of kind ``rezero`` (offset) or
    ``sensor_moved`` (P0 and offset)."""

    t: float
    row: int
    kind: StepKind


@dataclass(frozen=True)
class DriftModel:
    """The chosen basis: smooth-drift ``knots`` (times, empty for none) and ``steps``.

    ``time_unit`` is ``"s"`` (from ``t_s``) or ``"row"`` (row order).
    """

    knots: tuple[float, ...] = ()
    steps: tuple[Step, ...] = ()
    time_unit: str = "row"

    @property
    def is_none(self) -> bool:
        return not self.knots and not self.steps

    @property
    def name(self) -> str:
        if self.is_none:
            return "none"
        parts = (["steps"] if self.steps else []) + (["smooth"] if self.knots else [])
        return "+".join(parts)

    @property
    def n_columns(self) -> int:
        smooth = max(len(self.knots) - 1, 0)
        return smooth + sum(1 if s.kind == "rezero" else 4 for s in self.steps)

    def basis(self, t: FloatArray, unit: FloatArray) -> FloatArray:
        """Basis ``B`` (n, m) [mm per mm of coefficient] at times ``t`` (n,) with the unit
        vectors ``unit`` (n, 3) from ``P0`` to the tool."""
        cols: list[FloatArray] = []
        if self.knots:
            cols.extend(hats(np.asarray(self.knots), t)[:, 1:].T)
        for s in self.steps:
            h = (t >= s.t).astype(float)
            cols.append(h)
            if s.kind == "sensor_moved":
                cols.extend((-unit * h[:, None]).T)
        if not cols:
            return np.zeros((t.shape[0], 0))
        return np.column_stack(cols)

    def offset_curve(self, beta: FloatArray, t: FloatArray) -> FloatArray:
        """The offset change (n,) [mm] at times ``t`` (steps' offsets and the smooth drift,
        without the P0 moves' projection), relative to the first knot."""
        unit = np.zeros((t.shape[0], 3))
        b = self.basis(t, unit)
        return np.asarray(b @ beta, dtype=float)


def hats(knots: FloatArray, t: FloatArray) -> FloatArray:
    """Piecewise-linear hat functions (n, K) at ``t`` (n,) for ``knots`` (K,) ascending,
    constant beyond the ends (they sum to 1)."""
    tt = np.clip(t, knots[0], knots[-1])
    eye = np.eye(knots.shape[0])
    return np.column_stack([np.interp(tt, knots, eye[j]) for j in range(knots.shape[0])])


@dataclass
class Selection:
    """What :func:`select` chose and why: the model, and BIC per candidate."""

    model: DriftModel
    bic: dict[str, float] = field(default_factory=dict)
    rss_mm2: dict[str, float] = field(default_factory=dict)
    press_mm2: dict[str, float] = field(default_factory=dict)
    excluded_rows: list[int] = field(default_factory=list)


class _Linear:
    """The linearised problem at the plain fit: residual ``r`` (N,) [mm] orthogonal to the
    Jacobian's span, the data rows first (``n`` of them, in training order)."""

    def __init__(self, residual: FloatArray, jacobian: FloatArray, n: int) -> None:
        self.n = n
        self.q = orthonormal(jacobian)
        self.r = residual - self.q @ (self.q.T @ residual)
        self.rss0 = float(self.r @ self.r)

    def pad(self, b: FloatArray) -> FloatArray:
        out = np.zeros((self.r.shape[0], b.shape[1]))
        out[: self.n] = b
        return out

    def _added(self, b: FloatArray) -> FloatArray:
        """Orthonormal basis of the columns ``b`` (n, m) of the data rows, made orthogonal
        to the Jacobian's span."""
        bp = self.pad(b)
        bp = bp - self.q @ (self.q.T @ bp)
        return orthonormal(bp)

    def _rss_with(self, qb: FloatArray) -> float:
        proj = qb.T @ self.r
        return max(self.rss0 - float(proj @ proj), 1e-300)

    def rss(self, b: FloatArray) -> float:
        """RSS after adding the columns ``b`` (n, m) of the data rows."""
        if b.shape[1] == 0:
            return self.rss0
        return self._rss_with(self._added(b))

    def press(self, b: FloatArray) -> float:
        """Leave-one-out prediction error sum of squares [mm²] of the data rows with the
        columns ``b`` (n, m) added (``Σ (r_i / (1 − h_ii))²``, ``h`` the hat matrix of the
        stacked Jacobian and ``b``): held-out cross-validation within the training rows."""
        return (self.with_columns(b) if b.shape[1] else self)._press()

    def rss_press(self, b: FloatArray) -> tuple[float, float]:
        """:meth:`rss` and :meth:`press` of the columns ``b`` (n, m), orthonormalised once."""
        if b.shape[1] == 0:
            return self.rss0, self._press()
        qb = self._added(b)
        return self._rss_with(qb), self._extended(qb)._press()

    def _press(self) -> float:
        h = np.sum(self.q[: self.n] ** 2, axis=1)
        r = self.r[: self.n] / np.maximum(1.0 - h, 1e-6)
        return float(r @ r)

    def with_columns(self, b: FloatArray) -> _Linear:
        """The same problem with the columns ``b`` (n, m) added to the Jacobian."""
        if b.shape[1] == 0:
            return self
        return self._extended(self._added(b))

    def _extended(self, qb: FloatArray) -> _Linear:
        """The problem with the orthonormal columns ``qb`` (from :meth:`_added`) added."""
        out = _Linear.__new__(_Linear)
        out.n = self.n
        out.q = np.hstack([self.q, qb])
        out.r = self.r - qb @ (qb.T @ self.r)
        out.rss0 = float(out.r @ out.r)
        return out


def _bic(rss: float, n: int, params: int) -> float:
    return float(n * np.log(rss / n) + params * np.log(n))


def _scan(
    lin: _Linear, order: np.ndarray, unit: FloatArray, n_cols: int, taken: list[int]
) -> tuple[int, float]:
    """Best change point for a step of ``n_cols`` columns (1: re-zero, 4: sensor moved).

    ``order`` (n,) sorts the training rows by time. Returns the position in that order of
    the first row after the change, and the RSS drop [mm²]; position -1 if none is allowed.
    Every split is scored in one pass: for ``v_a`` the step's column profiles, the projected
    Gram matrix and right-hand side at each split are reverse cumulative sums.
    """
    n = lin.n
    least = MIN_SEGMENT_ROWS if n_cols == 1 else MIN_MOVE_ROWS
    if n < 2 * least:
        return -1, 0.0
    v = np.ones((n, 1)) if n_cols == 1 else np.column_stack([np.ones(n), -unit])
    v = v[order]
    q = lin.q[:n][order]  # (n, p) data rows of Q in time order (prior rows never step)
    r = lin.r[:n][order]

    def rev(a: FloatArray) -> FloatArray:
        return np.cumsum(a[::-1], axis=0)[::-1]

    c = np.stack([rev(q * v[:, a : a + 1]) for a in range(n_cols)], axis=1)  # (n, cols, p)
    raw = rev(v[:, :, None] * v[:, None, :])  # (n, cols, cols)
    gram = raw - np.einsum("kap,kbp->kab", c, c)
    rhs = rev(r[:, None] * v)  # (n, cols); Qᵀ r = 0
    ks = np.arange(least, n - least + 1)
    if n_cols == 1:  # 1×1 Gram matrices: the pseudo-inverse is 1/g (0 where g is 0)
        g = gram[ks, 0, 0]
        sol = np.divide(rhs[ks], g[:, None], out=np.zeros_like(rhs[ks]), where=g[:, None] > 0)
    else:
        pinv = np.linalg.pinv(gram[ks], rcond=1e-8, hermitian=True)
        sol = np.einsum("kab,kb->ka", pinv, rhs[ks])
    drop = np.einsum("ka,ka->k", rhs[ks], sol)
    for p in taken:  # a segment between two steps is at least as long as one at the ends
        drop[np.abs(ks - p) < least] = -np.inf
    if not np.isfinite(drop).any():
        return -1, 0.0
    best = int(np.argmax(drop))
    return int(ks[best]), float(drop[best])


def _steps(
    lin: _Linear,
    t: FloatArray,
    rows: np.ndarray,
    unit: FloatArray,
    n_bic: int,
    base_params: int,
) -> tuple[list[Step], FloatArray, float]:
    """Binary segmentation on top of ``lin``: change points kept while they lower BIC.

    Returns the steps, their basis (n, m) and the final BIC.
    """
    order = np.argsort(t, kind="stable")
    steps: list[Step] = []
    cols = np.zeros((lin.n, 0))
    params = base_params
    cur = lin
    bic = _bic(cur.rss0, n_bic, params)
    taken: list[int] = []
    for _ in range(MAX_STEPS):
        best: tuple[float, Step, FloatArray, int, int] | None = None
        for kind, n_cols in (("rezero", 1), ("sensor_moved", 4)):
            pos, drop = _scan(cur, order, unit, n_cols, taken)
            if pos < 0 or drop < MIN_GAIN * cur.rss0:
                continue
            rss = max(cur.rss0 - drop, 1e-300)
            cand = _bic(rss, n_bic, params + n_cols + 1)
            if best is None or cand < best[0]:
                i, before = int(order[pos]), int(order[pos - 1])
                mid = 0.5 * (float(t[i]) + float(t[before]))  # held-out rows between: half each
                step = Step(t=mid, row=int(rows[i]), kind=kind)  # type: ignore[arg-type]
                b = DriftModel(steps=(step,)).basis(t, unit)
                best = (cand, step, b, n_cols + 1, pos)
        if best is None or best[0] >= bic:
            break
        bic, step, b, extra, pos = best
        steps.append(step)
        taken.append(pos)
        cols = np.hstack([cols, b])
        params += extra
        cur = cur.with_columns(b)
    steps.sort(key=lambda s: s.t)
    return steps, cols, bic


def select(
    mode: DriftMode,
    residual: FloatArray,
    jacobian: FloatArray,
    t: FloatArray,
    rows: np.ndarray,
    unit: FloatArray,
    time_unit: str,
) -> Selection:
    """Choose the drift model for ``mode`` at the plain fit.

    Parameters
    ----------
    residual : ndarray, shape (N,)
        Stacked residual of the plain fit, the ``n`` data rows first, then the prior rows [mm].
    jacobian : ndarray, shape (N, k)
        Its Jacobian in the free parameters.
    t : ndarray, shape (n,)
        Capture time of the training rows [s, or row index].
    rows : ndarray of int, shape (n,)
        Their indices in the samples (to report a step's row).
    unit : ndarray, shape (n, 3)
        Unit vectors from ``P0`` to the tool at the plain fit.
    """
    n = t.shape[0]
    if n < MIN_ROWS:
        return _select_once("none", _Linear(residual, jacobian, n), t, rows, unit, time_unit)
    # Gross outliers of the plain fit first (beyond GROSS_SIGMA robust σ of its residual: a
    # drift widens that spread, so its rows stay in).
    lin = _Linear(residual, jacobian, n)  # reused below while the rows stay the same
    plain = np.abs(lin.r[:n])
    gross0 = plain > GROSS_SIGMA * 1.4826 * median(plain)
    if gross0.any():
        keep0 = np.concatenate([~gross0, np.ones(residual.shape[0] - n, dtype=bool)])
        residual, jacobian = residual * keep0, jacobian * keep0[:, None]
        lin = _Linear(residual, jacobian, n)
    sel = _select_once(mode, lin, t, rows, unit, time_unit)
    sel.excluded_rows = [int(v) for v in rows[gross0]]
    if sel.model.is_none:
        return sel
    # Gross outliers (beyond GROSS_SIGMA robust σ of the residual the chosen model leaves)
    # would pass for steps: choose again without them (the robust step screens them later).
    lin = lin.with_columns(sel.model.basis(t, unit))
    r = lin.r[:n]
    scale = 1.4826 * median(np.abs(r))
    gross = np.abs(r) > GROSS_SIGMA * scale
    if not gross.any() or scale <= 0:
        return sel
    keep = np.concatenate([~gross, np.ones(residual.shape[0] - n, dtype=bool)])
    again = _select_once(
        mode, _Linear(residual * keep, jacobian * keep[:, None], n), t, rows, unit, time_unit
    )
    again.excluded_rows = sorted({*sel.excluded_rows, *(int(v) for v in rows[gross])})
    return again


def _select_once(
    mode: DriftMode,
    lin: _Linear,
    t: FloatArray,
    rows: np.ndarray,
    unit: FloatArray,
    time_unit: str,
) -> Selection:
    """One pass of :func:`select` over the rows of ``lin`` (the linearised plain fit)."""
    n = t.shape[0]
    sel = Selection(DriftModel(time_unit=time_unit))
    sel.bic["none"] = _bic(lin.rss0, n, 0)
    sel.rss_mm2["none"] = lin.rss0
    if mode == "none" or n < 2 * MIN_SEGMENT_ROWS:
        return sel
    cands: dict[str, tuple[float, DriftModel]] = {"none": (sel.bic["none"], sel.model)}
    t0, t1 = float(t.min()), float(t.max())
    if mode in ("auto", "smooth") and t1 > t0:
        best_k: tuple[float, tuple[float, ...], float] | None = None
        for k in KNOT_CHOICES:
            if k * ROWS_PER_KNOT > n and k > 2:
                break
            knots = tuple(float(v) for v in np.linspace(t0, t1, k))
            b = DriftModel(knots=knots).basis(t, unit)
            rss = lin.rss(b)
            score = _bic(rss, n, k - 1)
            sel.bic[f"smooth{k}"] = score
            sel.rss_mm2[f"smooth{k}"] = rss
            if best_k is None or score < best_k[0]:
                best_k = (score, knots, rss)
        if best_k is not None:
            cands["smooth"] = (best_k[0], DriftModel(knots=best_k[1], time_unit=time_unit))
            if mode == "smooth":
                cands.pop("none")
            elif mode == "auto":
                knots = best_k[1]
                b = DriftModel(knots=knots).basis(t, unit)
                steps, _, score = _steps(lin.with_columns(b), t, rows, unit, n, len(knots) - 1)
                if steps:
                    m = DriftModel(knots=knots, steps=tuple(steps), time_unit=time_unit)
                    cands["steps+smooth"] = (score, m)
                    sel.bic["steps+smooth"] = score
    if mode in ("auto", "steps"):
        steps, _, score = _steps(lin, t, rows, unit, n, 0)
        if steps:
            cands["steps"] = (score, DriftModel(steps=tuple(steps), time_unit=time_unit))
            sel.bic["steps"] = score
    press0 = lin.press(np.zeros((n, 0)))
    sel.press_mm2["none"] = press0
    for name, (_, model) in list(cands.items()):
        if name == "none":
            continue
        b = model.basis(t, unit)
        sel.rss_mm2[name], sel.press_mm2[name] = lin.rss_press(b)
        if mode == "auto" and (
            sel.rss_mm2[name] > (1.0 - MIN_GAIN) * lin.rss0
            or sel.press_mm2[name] > (1.0 - MIN_GAIN) * press0
        ):
            cands.pop(name)
    sel.model = min(cands.values(), key=lambda c: c[0])[1]
    return sel


#: Methods whose solvers see the problem through ``Problem.evaluate`` (the drift's projection).
DRIFT_METHODS = ("geolm", "lm", "vslm")


def select_at_plain_fit(
    mode: DriftMode,
    problem: Problem,
    t: FloatArray,
    rows: np.ndarray,
    units: Callable[[FloatArray], FloatArray],
    time_unit: str,
) -> tuple[Selection, FloatArray]:
    """:func:`select` at the plain fit of ``problem`` (MAP or ML, no drift basis) by geodesic
    LM (:data:`calib.anchors.PLAIN_FIT`) from its start. ``t`` (n,) and ``rows`` (n,) as for
    :func:`select`; ``units(theta)`` gives the unit vectors (n, 3) from ``P0`` to the tool of
    the training rows under the full vector ``theta`` (p,). Returns the selection and those
    unit vectors at the plain fit (the chosen model's basis needs them)."""
    x = geolm.descend(problem, problem.x0(), PLAIN_FIT).x
    ev = problem.evaluate(x)
    assert ev.jacobian is not None
    unit = units(problem.full(x))
    return select(mode, ev.residual, ev.jacobian, t, rows, unit, time_unit), unit
