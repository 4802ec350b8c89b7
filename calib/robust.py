"""Robust fitting: the outlier screening of ``auto`` and ``reject``, and the IRLS weights.

Residuals are first made comparable. A row in the fit with leverage ``h_i`` (the diagonal of
the hat matrix of the stacked data + prior problem, :func:`leverage`: the prior's rows count,
so a parameter the prior holds does not make a row look more fitted than it is) has a residual
of variance ``σ²(1 − h_i)``; an excluded row's prediction error has ``σ²(1 + g_i)``. Dividing
by those factors gives studentised residuals ``t`` (:func:`screen`) of variance ``σ²``
each. ``Σ (1 − h_i)`` over the rows in the fit is the redundancy ``ν = n − p_eff``: the
degrees of freedom left after the fit, the prior's effective parameters included.

:func:`screen` standardises ``t`` by a robust scale (1.4826 × their median absolute deviation,
never below the indicator's resolution, :func:`calib.noise.noise_floor_mm`) and compares them
with a threshold. ``auto`` (the default) screens only when the redundancy is at least
:data:`calib.options.SCREEN_MIN_DOF`: below it, ``ν`` residuals carry the information of
``n`` rows, the scale is a guess, and an ordinary sample cannot be told from an outlier
(the screening then says so, and how many more rows would allow it). Its threshold is the
quantile of Student's t with ``ν − 1`` degrees of freedom (the scale estimated without the
tested row) at which ``n`` clean Gaussian rows have a :data:`AUTO_FALSE_FLAG_PROBABILITY`
chance of any flag (at least ``flag_threshold``): it grows with ``n``, and with the
uncertainty of the scale. At every redundancy a row whose deletion residual (its prediction
error from the fit without it, ``r_i / (1 − h_i)``) exceeds :data:`GROSS_ERROR_MM` is a gross
error and is rejected: no kinematic error leaves centimetres after an identification.

``auto`` and ``reject`` share one loop, :func:`solve`: a plain fit; flagged rows get
weight 0 and the method refits *from the start* (not from the contaminated solution); repeat
until the rejected set is stable. :data:`WEIGHTS` is the table ``robust`` option name → IRLS
weight function ``(u, k) -> w`` of standardised residuals ``u``, shape (n,), as scipy's
``least_squares`` keeps its losses.

The screening imports only numpy and the standard library (scipy.special only for a
Student-t quantile below :data:`T_EXPANSION_MIN_DOF` degrees of freedom, which ``auto`` never
asks for); :func:`solve` runs the method it is given (identify's: :func:`calib.methods.run`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from statistics import NormalDist

import numpy as np

from calib import noise
from calib.kinematics import FloatArray
from calib.options import SCREEN_MIN_DOF, RobustOptions, training_rows_recommended
from calib.problem import Problem
from calib.solvers.common import ProgressFn, SolverResult, sub_progress

#: Family-wise false-flag probability of ``auto`` on clean Gaussian data (all ``n`` rows).
AUTO_FALSE_FLAG_PROBABILITY = 0.01
#: A deletion residual beyond this is a gross error at any redundancy [mm].
GROSS_ERROR_MM = 10.0

WeightFn = Callable[[FloatArray, float], FloatArray]
#: ``(problem, x0, progress) -> result``: one fit of the method (identify's:
#: :func:`calib.methods.run` with the method's settings and the clock bound).
Fit = Callable[[Problem, FloatArray, "ProgressFn | None"], SolverResult]


def _none(u: FloatArray, k: float) -> FloatArray:
    return np.ones_like(u)


def _huber(u: FloatArray, k: float) -> FloatArray:
    return np.where(u <= k, 1.0, k / np.maximum(u, 1e-300))


def _soft_l1(u: FloatArray, k: float) -> FloatArray:
    return np.asarray(1.0 / np.sqrt(1.0 + (u / k) ** 2))


def _reject(u: FloatArray, k: float) -> FloatArray:
    return (u <= k).astype(float)


#: ``robust`` mode → weight function ``(u, k) -> w``. ``reject`` and ``auto`` are called with
#: their rejection threshold as ``k`` (samples beyond it get weight 0), the others with
#: ``robust_k``.
WEIGHTS: dict[str, WeightFn] = {
    "none": _none,
    "huber": _huber,
    "soft_l1": _soft_l1,
    "reject": _reject,
    "auto": _reject,
}

#: Modes that reject rows (weight 0) and refit from the start, rather than reweight.
REJECTING = ("reject", "auto")


#: Fewest degrees of freedom at which :func:`t_quantile` uses its expansion (0.5 % accurate
#: there at the tail probabilities of :func:`auto_threshold`); below, scipy's exact quantile.
T_EXPANSION_MIN_DOF = 9.0


def t_quantile(upper: float, dof: float) -> float:
    """The quantile of Student's t with ``dof`` degrees of freedom (inf: the Gaussian) that
    leaves ``upper`` (0 < upper < 0.5) above it. From ``dof`` >= :data:`T_EXPANSION_MIN_DOF` by
    the Cornish–Fisher expansion in ``1/dof`` around the Gaussian quantile (Abramowitz and
    Stegun 26.7.5; stdlib only, so identify does not import scipy.stats or scipy.special);
    below it by scipy.special, imported then."""
    z = NormalDist().inv_cdf(1.0 - upper)
    if not math.isfinite(dof):
        return z
    if dof < T_EXPANSION_MIN_DOF:
        from scipy.special import stdtrit  # lazily: few degrees of freedom only

        return float(-stdtrit(max(dof, 1.0), upper))
    g1 = (z**3 + z) / 4
    g2 = (5 * z**5 + 16 * z**3 + 3 * z) / 96
    g3 = (3 * z**7 + 19 * z**5 + 17 * z**3 - 15 * z) / 384
    g4 = (79 * z**9 + 776 * z**7 + 1482 * z**5 - 1920 * z**3 - 945 * z) / 92160
    return z + g1 / dof + g2 / dof**2 + g3 / dof**3 + g4 / dof**4


def auto_threshold(n: int, flag_threshold: float, dof: float = math.inf) -> float:
    """Rejection threshold of ``auto`` [robust σ] for ``n`` rows: at least ``flag_threshold``,
    and at least the two-sided quantile at which ``n`` clean rows have a
    :data:`AUTO_FALSE_FLAG_PROBABILITY` chance of any flag: of the Gaussian with the scale
    known (``dof`` inf), of Student's t with ``dof`` degrees of freedom for an estimated one
    (:func:`t_quantile`)."""
    upper = AUTO_FALSE_FLAG_PROBABILITY / (2 * max(n, 1))
    return max(flag_threshold, t_quantile(upper, dof))


def leverage(jac: FloatArray, w: FloatArray, prior_jac: FloatArray | None = None) -> FloatArray:
    """``g_i = j_i (J̃ᵀJ̃)⁺ j_iᵀ``, shape (n,), with ``J̃`` the stacked ``[sqrt(w) J; prior]``.

    ``jac`` (n, k) the unweighted Jacobian of the data residuals in the free parameters,
    ``w`` (n,) the weights of the fit, ``prior_jac`` (m, k) the prior rows' Jacobian (None:
    no prior). A row in the fit has leverage ``h_i = w_i g_i``. Columns are scaled to unit
    norm and the pseudo-inverse drops singular values below 1e-10 of the largest.
    """
    proj = _projection(jac, w, prior_jac)
    return np.asarray(np.sum(proj * proj, axis=1))


def _projection(jac: FloatArray, w: FloatArray, prior_jac: FloatArray | None) -> FloatArray:
    """``P`` (n, r) with ``P Pᵀ = J (J̃ᵀJ̃)⁺ Jᵀ``: the hat matrix of the rows in the fit is
    ``sqrt(w) P (sqrt(w) P)ᵀ`` (:func:`leverage`)."""
    stacked = np.sqrt(w)[:, None] * jac
    if prior_jac is not None and prior_jac.size:
        stacked = np.vstack([stacked, prior_jac])
    norms = np.linalg.norm(stacked, axis=0)
    norms = np.where(norms > 0, norms, 1.0)
    _, sv, vt = np.linalg.svd(stacked / norms, full_matrices=False)
    keep = sv > sv.max(initial=0.0) * 1e-10
    return np.asarray(((jac / norms) @ vt[keep].T) / sv[keep])


def median(values: FloatArray) -> float:
    """The median of ``values`` (any shape, taken flat), as ``np.median``: NaN when any value is
    NaN or there is none.

    Written here because ``np.median``'s first call imports ``numpy.ma`` (for a masked-array
    check), a cost every ``cablecal identify`` paid at its start; ``np.partition`` does not.
    """
    a = np.asarray(values, dtype=float).ravel()
    n = a.size
    if n == 0 or bool(np.isnan(a).any()):
        return math.nan
    k = n // 2
    if n % 2:
        return float(np.partition(a, k)[k])
    part = np.partition(a, (k - 1, k))
    return 0.5 * (float(part[k - 1]) + float(part[k]))


def _mad_scale(res: FloatArray, floor_mm: float) -> float:
    med = median(res)
    return max(1.4826 * median(np.abs(res - med)), floor_mm, 1e-6)


@dataclass(frozen=True)
class Screening:
    """The outlier screening of one fit (:func:`screen`).

    Attributes
    ----------
    u : ndarray, shape (n,)
        ``|t| / scale``: studentised residuals in robust σ.
    deletion_mm : ndarray, shape (n,)
        Each row's prediction error from the fit without it [mm]: ``r / (1 − h)`` for a row in
        the fit, ``r`` for an excluded one.
    scale_mm : float
        The robust scale of the studentised residuals of the rows in the fit [mm].
    redundancy : float
        ``ν = Σ (1 − h_i)`` over the rows in the fit: rows less effective parameters.
    threshold : float
        The flag threshold [robust σ]; inf when the screening is off.
    screening : bool
        Whether residuals are screened against ``threshold`` (``auto``: the redundancy is at
        least :data:`calib.options.SCREEN_MIN_DOF`); rows beyond :data:`GROSS_ERROR_MM` are
        flagged either way.
    n_in : int
        Rows in the fit.
    n_params : int
        Free parameters of the fit (the most effective parameters it can have).
    """

    u: FloatArray
    deletion_mm: FloatArray
    scale_mm: float
    redundancy: float
    threshold: float
    screening: bool
    n_in: int = 0
    n_params: int = 0

    def severity(self) -> FloatArray:
        """How far beyond its bound each row is, (n,): the larger of ``u`` over the threshold
        and the deletion residual over :data:`GROSS_ERROR_MM`; above 1 is flagged."""
        over = self.u / self.threshold if math.isfinite(self.threshold) else 0.0 * self.u
        return np.asarray(np.maximum(over, np.abs(self.deletion_mm) / GROSS_ERROR_MM))

    def flags(self) -> np.ndarray:
        """Rows beyond the threshold or the gross-error bound, bool (n,)."""
        return np.asarray(self.severity() > 1.0)

    def rejected(self, w: FloatArray) -> np.ndarray:
        """The rows the next fit leaves out, bool (n,), given this fit's weights ``w`` (n,):
        rows left out already that are still flagged, and the rows newly flagged whose
        severity is at least :data:`PEEL` of the largest newly flagged one. An outlier of
        centimetres pulls the fit and makes good rows look bad (their residuals and deletion
        residuals grow with it), so the grossest go first and the rest are judged again by
        the refit without them."""
        sev = self.severity()
        flagged = sev > 1.0
        new = flagged & (w > 0)
        if not new.any():
            return np.asarray(flagged)
        return np.asarray((flagged & (w == 0)) | (new & (sev >= PEEL * float(sev[new].max()))))

    def rows_short(self) -> int:
        """Rows in the fit that would let ``auto`` screen whatever the prior's share: those of
        the recommended count (:func:`calib.options.training_rows_recommended`, the free
        parameters plus :data:`calib.options.SCREEN_MIN_DOF`) less the rows in the fit; 0
        when it screens."""
        if self.screening:
            return 0
        return max(1, training_rows_recommended(self.n_params) - self.n_in)


def screen(
    mode: str,
    res: FloatArray,
    jac: FloatArray,
    w: FloatArray,
    prior_jac: FloatArray | None,
    flag_threshold: float,
    floor_mm: float = 0.0,
    screening: bool | None = None,
) -> Screening:
    """Screen the residuals of one fit for outliers.

    ``mode`` the ``robust`` option; ``res`` (n,) unweighted residuals [mm]; ``jac``, ``w``,
    ``prior_jac`` as for :func:`leverage`; ``flag_threshold`` the option [robust σ] (the
    threshold of ``reject``, huber's and soft-L1's flag, and the least threshold of ``auto``);
    ``floor_mm`` the least scale (:func:`calib.noise.noise_floor_mm`); ``screening`` whether
    ``auto`` screens, None to decide by the redundancy of this fit (the rejection loop decides
    on its first, plain fit and keeps the decision, so that rejecting rows near the bound does
    not switch the screening off and on).
    """
    proj = _projection(jac, w, prior_jac)
    g = np.sum(proj * proj, axis=1)
    inside = w > 0
    h = np.where(inside, w * g, 0.0)
    factor = np.clip(np.where(inside, 1.0 - h, 1.0 + g), 1e-6, None)
    t = res / np.sqrt(factor)
    deletion = np.where(inside, res / np.clip(1.0 - h, 1e-6, None), res)
    scale = _mad_scale(t[inside] if np.any(inside) else t, floor_mm)
    redundancy = float(np.sum(1.0 - h[inside]))
    n_in = int(np.count_nonzero(inside))
    if mode == "auto":
        if screening is None:
            screening = redundancy >= SCREEN_MIN_DOF
        thr = auto_threshold(n_in, flag_threshold, redundancy - 1.0) if screening else math.inf
    else:
        screening, thr = True, flag_threshold
    u = np.abs(t) / scale
    if mode in REJECTING and bool(screening) and np.all((w == 0) | (w == 1)):
        u = _unmasked(np.sqrt(w)[:, None] * proj, res, t, inside, scale, floor_mm)
    return Screening(u, deletion, scale, redundancy, thr, bool(screening), n_in, int(jac.shape[1]))


#: Share of the largest severity a newly flagged row needs to be rejected in the same round
#: (:meth:`Screening.rejected`).
PEEL = 0.1
#: The backward search (:func:`_unmasked`) sets rows aside only when that cuts the robust
#: scale of the rest to this share of the scale before, or less: outliers of millimetres that
#: mask each other inflate it tens of times on low-noise cells, while deleting up to ten of
#: the largest good rows shrinks it only a few times (their residuals are the tails, and each
#: deletion takes a degree of freedom).
SCALE_DROP = 0.1
#: The backward search keeps the first deleted set whose scale is within this factor of the
#: least along its path (the elbow).
ELBOW = 1.5
#: Most rows the backward search deletes (it also stops where the rest would have less than
#: :data:`calib.options.SCREEN_MIN_DOF` redundancy, and at a fifth of the rows).
MAX_DELETIONS = 10


def _unmasked(
    a: FloatArray,
    res: FloatArray,
    t: FloatArray,
    inside: np.ndarray,
    scale: float,
    floor_mm: float,
) -> FloatArray:
    """Standardised residuals (n,) once outliers that mask each other are set aside: a
    backward search in the linearised fit.

    With few rows to spare, a least-squares fit spreads an outlier over the other residuals
    (``r = (I − H) e``), so two outliers can inflate the MAD scale until neither stands out.
    Deleting a set ``S`` of rows from the fit changes the other rows' residuals to
    ``r + H_{·S} (I − H_SS)⁻¹ r_S`` and leverages to ``h + diag(H_{·S} (I − H_SS)⁻¹ H_{S·})``
    without a refit. Rows are deleted one at a time, the largest studentised residual of the
    rest first (at most :data:`MAX_DELETIONS`, a fifth of the rows, and while the rest keep the
    redundancy screening needs, :data:`calib.options.SCREEN_MIN_DOF`). If the smallest robust
    scale of the rest along the way is at most :data:`SCALE_DROP` of the scale before, the
    first deleted set whose scale is within :data:`ELBOW` of that smallest is judged by its
    prediction errors ``((I − H_SS)⁻¹ r_S)_i / sqrt(((I − H_SS)⁻¹)_ii)`` over the scale of the
    rest. The other rows keep their standardised residuals until the refit without the rows
    flagged: the linearisation is rough while centimetres pull the fit, and could make good
    rows look like outliers. ``a`` (n, r): the rows in the fit's factor of the hat matrix
    ``H = a aᵀ`` (zero rows for excluded rows); ``t`` (n,) the studentised residuals [mm].
    """
    deleted: list[int] = []
    u0 = np.abs(t) / scale
    u = u0
    h0 = np.sum(a * a, axis=1)  # the leverages in the fit, the same for every trial
    path: list[tuple[list[int], FloatArray, float]] = []
    for _ in range(min(MAX_DELETIONS, int(np.count_nonzero(inside)) // 5)):
        cand_u = u.copy()
        cand_u[~inside] = -1.0
        cand_u[deleted] = -1.0
        trial = [*deleted, int(np.argmax(cand_u))]
        new_u, new_scale, redundancy = _deleted(a, h0, res, t, inside, trial, floor_mm)
        if redundancy < SCREEN_MIN_DOF:
            break
        deleted, u = trial, new_u
        path.append((trial, new_u, new_scale))
    least = min((sc for _, _, sc in path), default=scale)
    if least > SCALE_DROP * scale:
        return u0
    # the first set that comes close to the least scale: deleting more good rows after the
    # outliers only trims the tails of the rest and shrinks its scale a little further
    rows, u_set, _ = next(p for p in path if p[2] <= ELBOW * least)
    out = u0.copy()
    out[rows] = u_set[rows]
    return out


def _deleted(
    a: FloatArray,
    h0: FloatArray,
    res: FloatArray,
    t: FloatArray,
    inside: np.ndarray,
    deleted: list[int],
    floor_mm: float,
) -> tuple[FloatArray, float, float]:
    """:func:`_unmasked`'s standardised residuals (n,), scale [mm] and redundancy with
    ``deleted`` rows out of the linearised fit; ``h0`` (n,) the leverages ``Σ a²`` per row."""
    a_s = a[deleted]  # (s, r)
    m = np.linalg.pinv(np.eye(len(deleted)) - a_s @ a_s.T)  # (I − H_SS)⁻¹
    cross = a @ a_s.T  # H_{·S}, (n, s)
    e_s = m @ res[deleted]
    r_new = res + cross @ e_s
    h_new = h0 + np.sum((cross @ m) * cross, axis=1)
    rest = inside.copy()
    rest[deleted] = False
    t_new = np.where(rest, r_new / np.sqrt(np.clip(1.0 - h_new, 1e-6, None)), t)
    t_new[deleted] = e_s / np.sqrt(np.clip(np.diag(m), 1e-6, None))
    scale = _mad_scale(t_new[rest], floor_mm)
    return np.abs(t_new) / scale, scale, float(np.sum(1.0 - h_new[rest]))


#: Most fits of the rejecting modes (the first, plain fit included).
REJECT_ROUNDS = 5


@dataclass
class Solved:
    """What :func:`solve` found: the last solver result (iterations summed over rounds), the
    problem with the final weights, the standardised residuals of the training rows (shape
    (n_train,)), the flag threshold [robust σ], the rows flagged (indices into the training
    rows), the number of fits run and the last screening (None without a robust mode)."""

    result: SolverResult
    problem: Problem
    u: FloatArray
    threshold: float
    flagged: np.ndarray
    fits: int
    screening: Screening | None = None


def _screen_fit(
    problem: Problem,
    x: FloatArray,
    w: FloatArray,
    opts: RobustOptions,
    floor_mm: float,
    first: Screening | None,
) -> Screening:
    """The outlier screening of every training row at ``x`` under weights ``w`` (n,), the
    prior's rows counted in the leverage (:func:`screen`); whether ``auto`` screens is decided
    on the ``first`` (plain) fit. ``problem`` has unit weights, so its Jacobian's data rows are
    the unweighted ones."""
    ev = problem.evaluate(x)
    assert ev.jacobian is not None
    n = problem.n_samples
    prior_jac = ev.jacobian[n:] if problem.has_prior else None
    return screen(
        opts.robust,
        ev.residual[:n],
        ev.jacobian[:n],
        w,
        prior_jac,
        opts.flag_threshold,
        floor_mm,
        None if first is None else first.screening,
    )


def solve(problem: Problem, opts: RobustOptions, fit: Fit, progress: ProgressFn | None) -> Solved:
    """Run the method; robustly, as IRLS rounds (huber, soft_l1) or as rejection rounds
    (reject, auto; each refit starts from the common start, not from the contaminated
    solution, so an outlier's pull does not carry over). ``fit`` runs the method once
    (:data:`Fit`)."""
    n = problem.length_mm.size
    thr = opts.flag_threshold
    floor_mm = noise.noise_floor_mm(problem.length_mm)
    rejecting = opts.robust in REJECTING
    weights = np.ones(n)
    scr: Screening | None = None
    first: Screening | None = None
    rounds = 1 if opts.robust == "none" else REJECT_ROUNDS if rejecting else 8
    seen: list[FloatArray] = []
    result: SolverResult | None = None
    total_iter, fits = 0, 0
    history: list[float] = []
    starts: list[int] = []
    x = problem.x0()
    u = np.zeros(n)
    for r in range(rounds):
        prob_r = problem.with_weights(weights)
        lo = 0.05 + 0.9 * r / rounds
        start = problem.x0() if rejecting else x
        result = fit(prob_r, start, sub_progress(progress, lo, lo + 0.9 / rounds))
        total_iter += result.iterations
        fits += 1
        starts.append(len(history))
        history.extend(result.cost_history_rms_mm)
        x = result.x
        if opts.robust == "none":
            break
        scr = _screen_fit(problem, x, weights, opts, floor_mm, first)
        first = first or scr
        u, thr = scr.u, scr.threshold
        if rejecting:
            new_w = (~scr.rejected(weights)).astype(float)
        else:
            new_w = WEIGHTS[opts.robust](u, opts.robust_k)
        if np.max(np.abs(new_w - weights)) < 1e-3 or r == rounds - 1:
            break  # converged, or out of rounds: keep the weights the last fit used
        if rejecting and any(np.array_equal(new_w, w) for w in seen):
            break  # a cycle of rejected sets (model error near the threshold): stop
        seen.append(weights)
        weights = new_w
    assert result is not None
    result.iterations = total_iter
    result.cost_history_rms_mm, result.fit_starts = history, starts
    flagged = np.flatnonzero(weights == 0) if rejecting else np.flatnonzero(u > thr)
    return Solved(result, problem.with_weights(weights), u, thr, flagged, fits, scr)
