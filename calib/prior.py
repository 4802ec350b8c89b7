"""The MAP prior's weight, chosen so that it keeps its meaning as the number of samples grows.

The MAP problem (:mod:`calib.problem`) adds rows ``noise_mm · (x_j − μ_j)/σ_j`` to the data
residuals ``L_model − L``. Its minimiser is the posterior mode only if ``noise_mm`` is the real
1σ of the length residuals. A fixed ``noise_mm`` ten times below the residuals' real 1σ weighs
the prior ``(1/10)² = 1/100`` of what it should. ``prior_weight`` chooses it:

``estimated`` (default)
    ``noise_mm`` = ``σ̂ = sqrt(Σ w r² / (n_w − k_eff))`` of the MAP fit's own residuals, with
    ``k_eff`` the effective number of parameters (:func:`effective_dof`: the trace of the data
    rows' block of the hat matrix of the stacked data + prior problem), iterated to a fixed point:
    fit with ``noise_mm``, estimate ``σ̂``, refit with it until they agree within
    :data:`NOISE_RTOL` (at most :data:`NOISE_ROUNDS` fits; :func:`noise_from_map`). This is the
    empirical-Bayes choice: the prior widths keep their meaning as plausible DH errors, and the
    noise is the data's own. It used to be the σ̂ of a maximum-likelihood fit first; on local
    data (the bundled set) that fit slides metres along an unexcited valley and takes many
    iterations for a noise figure the MAP fit gives in two cheap fits.
``fixed``
    ``noise_mm`` as given (the option; :data:`calib.options.IDENTIFY_NOISE_MM` by default).
``cv``
    ``σ̂`` as above, then the prior widths scaled by each of :data:`CV_SCALES` (and no prior at
    all) are scored by grouped-fold cross-validation on the training rows
    (:func:`cv_scale`: :data:`CV_FOLDS` folds of whole pose groups, plain LM fits): the scale with
    the lowest mean held-out RMSE is used. This is the honest way to choose a weight for
    accuracy at poses unlike the training poses; it costs ``CV_FOLDS × (len(CV_SCALES) + 1)``
    extra fits.

A prior cannot make data excite parameters they do not excite: measured on the bundled data in
``bench/prior_weight.md`` (see docs/calibration-results.md).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from calib.cable import N_DH, N_KIN
from calib.kinematics import FloatArray
from calib.methods import internal_sigma
from calib.noise import median_dof, noise_floor_mm
from calib.problem import Problem
from calib.robust import Solved, auto_threshold, leverage
from calib.solvers.common import ProgressFn, report

if TYPE_CHECKING:
    from calib.options import PriorOptions

#: ``(prior, train_rows, test_rows) -> held-out RMSE [mm]`` of one identification with the
#: prior options ``prior`` on the samples :func:`cv_scale` scores (identify passes a plain LM
#: :func:`calib.identify.identify`, so that this module does not import it back).
HeldOutRmse = Callable[["PriorOptions", np.ndarray, np.ndarray], float]
#: ``problem -> the robust fit`` (:func:`calib.robust.solve` with identify's robust options
#: and method).
RobustFit = Callable[[Problem], Solved]

#: Most MAP fits of the ``estimated`` fixed point.
NOISE_ROUNDS = 4
#: The fixed point is reached when ``|σ̂ / noise_mm − 1|`` is below this.
NOISE_RTOL = 0.1

#: Multipliers of the prior widths (``prior_mm``, ``prior_deg``) that ``cv`` scores; ``inf``
#: (no prior) is scored too.
CV_SCALES: tuple[float, ...] = (0.25, 1.0, 4.0, 16.0)
#: Folds of whole pose groups in ``cv``.
CV_FOLDS = 3
#: Fewest training rows per fold fit in ``cv``; folds below it are skipped.
CV_MIN_TRAIN = 30


def with_prior(problem: Problem, options: PriorOptions) -> Problem:
    """``problem`` with the MAP prior rows ``options`` ask for (itself without a prior).

    Prior 1σ: ``prior_mm`` per DH length, ``prior_deg`` per DH angle, ``prior_tool_mm`` per
    tool coordinate (none by default), none on the anchors; mean: the problem's ``theta0``
    with the DH errors (and, with ``prior_tool_mm``, the tool error) at 0, i.e. the nominal
    model with the fitted anchors; rows weighed by ``noise_mm``. identify's MAP problem, and
    the benchmark's and tests' rebuilds of it.
    """
    if not options.prior:
        return problem
    layout = problem.layout
    sigma = internal_sigma(layout, options.prior_mm, options.prior_deg, np.inf)
    tool_sigma = options.prior_tool_mm
    sigma[N_DH:N_KIN] = np.inf if tool_sigma is None else tool_sigma
    mean = problem.theta0.copy()
    mean[:N_DH] = 0.0
    if tool_sigma is not None:
        mean[N_DH:N_KIN] = 0.0
    return replace(problem, prior_sigma=sigma, prior_mean=mean, noise_mm=options.noise_mm)


def effective_dof(problem: Problem, x: np.ndarray) -> float:
    """Effective number of parameters the data rows use at free values ``x`` (shape (k,)).

    The trace of the data rows' block of the hat matrix ``H = J̃ (J̃ᵀJ̃)⁺ J̃ᵀ`` of the stacked
    (weighted data + prior rows) Jacobian ``J̃`` (shape (n[+k], k)): ``k`` without a prior (or
    fewer where the Jacobian is rank deficient), less with one, down to 0 for parameters only
    the prior holds. Computed from the SVD of the column-scaled ``J̃`` (rank by a relative
    singular-value threshold of 1e-12 · max(shape)).
    """
    ev = problem.evaluate(x)
    assert ev.jacobian is not None
    return _data_hat_trace(ev.jacobian, problem.n_samples)


def _data_hat_trace(jac: np.ndarray, n: int) -> float:
    """:func:`effective_dof` from the stacked Jacobian (shape (n[+k], k)), ``n`` data rows."""
    return _data_hat(jac, n)[0]


def _data_hat(jac: np.ndarray, n: int) -> tuple[float, float]:
    """``tr H`` and ``tr H²`` of the data rows' block ``H`` (n, n) of the stacked Jacobian's
    (shape (n[+k], k)) hat matrix."""
    norms = np.linalg.norm(jac, axis=0)
    norms[norms == 0.0] = 1.0
    u, s, _ = np.linalg.svd(jac / norms, full_matrices=False)
    if s.size == 0 or not s[0] > 0.0:
        return 0.0, 0.0
    keep = s > s[0] * 1e-12 * max(jac.shape)
    un = u[:n, keep]
    gram = un.T @ un  # H = un unᵀ: tr H² = ‖unᵀ un‖²
    return float(np.trace(gram)), float(np.sum(gram * gram))


@dataclass(frozen=True)
class HeldOutRows:
    """The held-out (test) rows of an identification: joints (m, 6) [rad], lengths (m,)
    [mm], anchor index (m,) into the problem's layout."""

    q_rad: FloatArray
    length_mm: FloatArray
    anchor_index: np.ndarray


def noise_from_map(problem: Problem, x: np.ndarray, held_out: HeldOutRows | None = None) -> float:
    """``σ̂ = sqrt(Σ w r² / m(ν))`` [mm] of the data residuals at free values ``x`` (shape
    (k,)), at least the lengths' own resolution (:func:`calib.noise.noise_floor_mm`).

    ``ν = n_w − k_eff`` are the degrees of freedom left after the fit: ``n_w`` the rows with
    non-zero weight (rejected outliers do not count), ``k_eff`` the effective number of
    parameters (:func:`effective_dof`: ``k`` for an ML fit of full rank, fewer with the prior),
    less the drift columns profiled out of the data rows (:attr:`Problem.n_drift`: their
    projection is a hat of its own, orthogonal to the projected Jacobian's), at least 1.
    ``m(ν)`` is the median of χ²(ν) (:func:`calib.noise.median_dof`), so the
    estimate is as often above the real noise as below it even with a few degrees of freedom
    (``Σ r² / ν`` is below it most of the time there), and ``≈ Σ r² / ν`` once ``ν`` is large.

    ``held_out`` rows (the test rows, never fitted) add what they know: each one's prediction
    error ``r_t`` has the variance ``σ² (1 + g_t)``, ``g_t`` its leverage against the fit
    (:func:`calib.robust.leverage`: the parameters' own uncertainty at that pose), so
    ``r_t² / (1 + g_t)`` is one more degree of freedom of ``σ²``. At the minimum sample count
    the training rows leave about 3 (25 rows, about 22 effective parameters on the HSR JR680)
    and the estimate spreads from a third to twice the truth; the 6 test rows triple that
    (measured in ``bench/min_n.md``). A held-out row whose studentised prediction error is a
    gross error (beyond :func:`calib.robust.auto_threshold` of Student's t with the training
    rows' ``ν``) is left out: test rows are not screened. The test rows only weigh the prior
    (this one number); the parameters are fitted to the training rows alone. identify passes
    them for a random hold-out only (rows like the training rows; a grouped hold-out's errors
    include the extrapolation to other poses), and not with drift columns (the drift at a
    test row is not in the fit).
    """
    ev = problem.evaluate(x)  # one model pass: the weighted residual and the Jacobian
    assert ev.jacobian is not None
    n = problem.n_samples
    weighted = ev.residual[:n]  # sqrt(w) · (L_model − L)
    n_w = int(np.count_nonzero(problem.weights > 0))
    tr_h, tr_h2 = _data_hat(ev.jacobian, n)
    dof = max(n_w - 2.0 * tr_h + tr_h2 - problem.n_drift, 1.0)
    rss = float(weighted @ weighted)
    lengths = problem.length_mm[problem.weights > 0]
    if held_out is not None and held_out.length_mm.size and problem.n_drift == 0:
        z = _held_out_terms(problem, x, ev.jacobian, held_out)
        limit = auto_threshold(n_w + z.size, 0.0, dof) ** 2 * rss / median_dof(dof)
        keep = z <= limit
        rss += float(np.sum(z[keep]))
        dof += float(np.count_nonzero(keep))
        lengths = np.concatenate([lengths, held_out.length_mm])
    estimate = float(np.sqrt(rss / median_dof(dof)))
    return max(estimate, noise_floor_mm(lengths))


def _held_out_terms(
    problem: Problem, x: np.ndarray, stacked_jac: FloatArray, held_out: HeldOutRows
) -> FloatArray:
    """``r_t² / (1 + g_t)`` [mm²] of the held-out rows (m,) at ``x``: prediction errors
    over their variance in units of ``σ²`` (``stacked_jac``: the fit's weighted data and
    prior rows, (n[+k], k))."""
    n, m = problem.n_samples, held_out.length_mm.shape[0]
    test = replace(
        problem,
        q_rad=held_out.q_rad,
        length_mm=held_out.length_mm,
        anchor_index=held_out.anchor_index,
        weights=np.ones(m),
        prior_sigma=None,
        prior_mean=None,
        drift_basis=None,
    )
    ev = test.evaluate(x)
    assert ev.jacobian is not None
    r_t, j_t = ev.residual[:m], ev.jacobian[:m]
    rows = np.vstack([stacked_jac[:n], j_t])  # the fit's rows (weighted) and the test rows
    g = leverage(rows, np.concatenate([np.ones(n), np.zeros(m)]), stacked_jac[n:])[n:]
    out: FloatArray = r_t**2 / (1.0 + g)
    return out


def scaled_options(options: PriorOptions, noise_mm: float, scale: float) -> PriorOptions:
    """The options the MAP fit runs with: ``noise_mm``, widths × ``scale`` (``inf``: no prior)."""
    if not np.isfinite(scale):
        return replace(options, prior=False, prior_weight="fixed", noise_mm=noise_mm)
    return replace(
        options,
        prior=True,
        prior_weight="fixed",
        noise_mm=noise_mm,
        prior_mm=options.prior_mm * scale,
        prior_deg=options.prior_deg * scale,
    )


def cv_scale(
    held_out_rmse: HeldOutRmse,
    labels: np.ndarray,
    options: PriorOptions,
    train_rows: np.ndarray,
    noise_mm: float,
) -> tuple[float, dict[str, float]]:
    """The prior-width scale with the lowest mean grouped-fold held-out RMSE on ``train_rows``.

    ``held_out_rmse`` fits one fold (:data:`HeldOutRmse`). Returns the scale (``inf`` = no
    prior) and the mean held-out RMSE [mm] per scale, keyed by the scale as text. ``labels``
    (shape (len(train_rows),)) are the training rows' pose groups, those of the grouped
    hold-out (:func:`calib.split.pose_groups`); each fold holds out every
    :data:`CV_FOLDS`-th group present in the training rows.
    """
    present = np.unique(labels)
    if present.size < 2:
        return 1.0, {}
    fold_of = {g: i % CV_FOLDS for i, g in enumerate(present)}
    folds = np.array([fold_of[g] for g in labels])
    scores: dict[str, float] = {}
    for scale in (*CV_SCALES, float("inf")):
        errs = []
        for f in range(min(CV_FOLDS, present.size)):
            tr, te = train_rows[folds != f], train_rows[folds == f]
            if tr.size < CV_MIN_TRAIN or te.size == 0:
                continue
            errs.append(held_out_rmse(scaled_options(options, noise_mm, scale), tr, te))
        if errs:
            scores[str(scale)] = float(np.mean(errs))
    if not scores:
        return 1.0, {}
    best = min(scores, key=lambda k: scores[k])
    return float(best), scores


def prior_block(
    options: PriorOptions, used: PriorOptions, detail: dict[str, Any]
) -> dict[str, Any]:
    """``result.json``'s ``prior``: asked (``used``), the widths and noise the fit ran with,
    and how the weight was chosen (``weight``, ``noise_estimated_mm``, ``cv_scale``, …)."""
    return {
        "used": options.prior,
        "dh_mm": used.prior_mm,
        "dh_deg": used.prior_deg,
        "tool_mm": options.prior_tool_mm,
        "noise_mm": used.noise_mm,
        "weight": options.prior_weight,
        "applied": used.prior,
        **detail,
    }


def weighed_solve(
    make_problem: Callable[[PriorOptions], Problem],
    theta_start: FloatArray,
    opts: PriorOptions,
    fit: RobustFit,
    held_out_rmse: HeldOutRmse,
    fold_labels: Callable[[], np.ndarray],
    train_rows: np.ndarray,
    progress: ProgressFn | None,
    held_out: HeldOutRows | None = None,
) -> tuple[PriorOptions, dict[str, Any], Solved]:
    """The fit (``fit``: :data:`RobustFit`), its prior weighed as ``prior_weight`` says.

    ``make_problem(options)`` builds the problem (ML, or MAP with the options' widths and
    noise) from the common start ``theta_start`` (p,). ``fixed`` (or no prior): one solve.
    ``estimated``: the noise fixed point, each round a MAP solve with the noise the last one
    estimated (from the option's ``noise_mm``), until ``σ̂`` agrees with the noise used within
    :data:`NOISE_RTOL`; the last round is the fit. ``held_out``: the test rows, which the
    noise estimate reads too (:func:`noise_from_map`). ``cv``: that noise, then the prior-width
    scale chosen by grouped-fold cross-validation on ``train_rows`` (:func:`cv_scale`, with
    ``held_out_rmse`` and the training rows' pose groups ``fold_labels()``), and a final
    solve. Returns the prior options the fit ran with, the detail for ``result.json`` and the
    solve.
    """
    if not opts.prior or opts.prior_weight == "fixed":
        return opts, {}, fit(make_problem(opts))
    used = opts
    noise = opts.noise_mm
    warm = theta_start  # each round starts where the last ended (the prior mean stays)
    for rounds in range(1, NOISE_ROUNDS + 1):
        report(progress, 0.05, f"MAP fit {rounds} for the noise estimate (noise {noise:.3g} mm)")
        solved = fit(make_problem(used).with_theta0(warm))
        noise = noise_from_map(solved.problem, solved.result.x, held_out)
        if abs(noise / used.noise_mm - 1.0) < NOISE_RTOL:
            break
        used = scaled_options(opts, noise, 1.0)
        warm = solved.problem.full(solved.result.x)
    detail: dict[str, Any] = {"noise_estimated_mm": noise, "noise_rounds": rounds}
    if opts.prior_weight == "estimated":
        return used, detail, solved
    report(progress, 0.1, "cross-validating the prior scale over pose groups")
    scale, scores = cv_scale(held_out_rmse, fold_labels(), opts, train_rows, used.noise_mm)
    detail |= {"cv_scale": scale if np.isfinite(scale) else None, "cv_rmse_mm": scores}
    used = scaled_options(opts, used.noise_mm, scale)
    return used, detail, fit(make_problem(used))
