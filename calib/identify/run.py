"""Identification of a robot's DH errors, tool point, anchors and zero offsets from cable lengths.

The public entry point is :func:`identify`. It

1. checks the options against the samples (:func:`calib.options.validate`) and splits them
   into training and test rows (random, grouped, or given; :mod:`calib.split`);
2. fits the *before* model: nominal kinematics with only ``P0`` and ``c`` per anchor, started
   by linear multilateration (:func:`calib.cable.multilaterate`) and refined by LM
   (:func:`calib.anchors.fit_anchors`);
3. starts the full identification from the nominal DH table with the tool point, ``P0`` and
   ``c`` fitted (so that every method starts from the same, data-driven point, and no manual
   guess is needed);
4. analyses identifiability at that point (:mod:`calib.identifiability`) and solves for the
   base parameter set, plus parameters freed by name, minus parameters fixed by name;
   then (``drift``, :func:`calib.drift.select_at_plain_fit`) tests the plain fit for steps
   and a smooth drift of the measurement over the campaign; a chosen model's terms are
   profiled out of the problem (:class:`calib.problem.Problem`'s drift basis) for every later
   fit, and the test rows' figures add them at each row's time;
5. weighs the optional Gaussian prior toward the nominal model (MAP) by the noise its own MAP
   fits estimate, or by grouped-fold cross-validation (:func:`calib.prior.weighed_solve`), and runs
   the chosen method (:data:`calib.methods.REGISTRY`), robustly by default: ``auto`` fits, tests
   the leverage-studentised residuals (prior included) against a MAD scale and a threshold
   growing with ``n`` and with the scale's uncertainty, when the redundancy allows screening,
   and only on outliers (or gross errors) rejects them and refits from the start; IRLS with Huber or
   soft-L1 weights, or rejection at 3.5σ, on request (:func:`calib.robust.solve`);
6. computes the covariance ``(JᵀJ/σ̂² + Σ_prior⁻¹)⁻¹`` with ``σ̂² = Σ w r² / (n − k)``, the
   metrics before and after on train and test, the plausibility of every parameter
   (:mod:`calib.identify.plausibility`) and the predicted tool-point σ after best rigid alignment
   (:mod:`calib.tcp`).

Units: inputs in degrees and millimetres; internal computation in radians and millimetres;
every reported figure in degrees and millimetres.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from calib import drift, methods, prior, robust
from calib.anchors import fit_anchors, plain_fit
from calib.cable import N_DH, N_KIN, ParamLayout, kinematic_parts, length_jacobian, predict_lengths
from calib.dataset import SampleError, SampleSet, validate_joint_limits
from calib.identifiability import (
    Identifiability,
    analyse,
    candidate_mask,
    generic_jacobian,
    solved_mask,
    with_tool,
)
from calib.identify.covariance import covariance, uncertainty
from calib.identify.plausibility import implausibility_advice, plausibility
from calib.identify.result_json import (
    IdentifyResult,
    drift_report,
    drift_summary,
    length_figures,
    robust_detail,
    robust_note,
)
from calib.kinematics import FloatArray, forward_position
from calib.models import RobotModel
from calib.options import (
    METHODS,
    DriftOptions,
    IdentifyOptions,
    PriorOptions,
    RobustOptions,
    SolverSettings,
    check_training_rows,
    part,
    with_part,
)
from calib.prior import prior_block
from calib.problem import Problem
from calib.solvers.common import ProgressFn, report
from calib.split import Checked, check, pose_groups, split_rows
from calib.tcp import tcp_uncertainty_for_problem
from calib.timing import Clock, Timer

__all__ = [
    "METHODS",
    "IdentifyOptions",
    "IdentifyResult",
    "identify",
    "identify_checked",
    "pose_groups",
    "split_rows",
]


@dataclass
class _Data:
    """The samples of one identification, split: all rows and the training rows."""

    model: RobotModel  # with the tool override applied
    layout: ParamLayout
    samples: SampleSet
    q_all: FloatArray  # (n, 6) [rad]
    aidx_all: np.ndarray  # (n,) anchor index per sample
    train_rows: np.ndarray  # (n_train,)
    test_rows: np.ndarray  # (n_test,)
    drift_model: drift.DriftModel | None = None  # chosen by _select_drift, None: no drift
    drift_basis: FloatArray | None = None  # (n_train, m) its basis at the training rows

    @property
    def times(self) -> tuple[FloatArray, str]:
        """Capture time of every sample (n,) [s, from ``t_s``; else the row index] and unit."""
        if self.samples.t_s is not None:
            return np.asarray(self.samples.t_s, dtype=float), "s"
        return np.arange(len(self.samples), dtype=float), "row"

    def units(self, theta: FloatArray, rows: np.ndarray) -> FloatArray:
        """Unit vectors (r, 3) from each row's ``P0`` to the tool under ``theta``."""
        dh, tool = kinematic_parts(self.model, theta)
        pos = forward_position(dh, self.q_all[rows], tool, self.model.convention)
        diff = pos - theta[N_KIN:].reshape(-1, 4)[self.aidx_all[rows], :3]
        out: FloatArray = diff / np.maximum(np.linalg.norm(diff, axis=1), 1e-9)[:, None]
        return out

    @property
    def q(self) -> FloatArray:
        """Training joint angles, shape (n_train, 6) [rad]."""
        return np.asarray(self.q_all[self.train_rows], dtype=float)

    @property
    def aidx(self) -> np.ndarray:
        """Training anchor index per sample, shape (n_train,)."""
        return np.asarray(self.aidx_all[self.train_rows])

    @property
    def length_mm(self) -> FloatArray:
        """Training cable lengths, shape (n_train,) [mm]."""
        return np.asarray(self.samples.length_mm[self.train_rows], dtype=float)

    def lengths(self, theta: FloatArray, rows: np.ndarray) -> FloatArray:
        """Predicted lengths [mm] of ``rows`` (shape (r,)) under ``theta``."""
        if rows.size == 0:
            return np.zeros(0)
        return predict_lengths(self.model, theta, self.q_all[rows], self.aidx_all[rows])


def _prepare(model: RobotModel, samples: SampleSet, checked: Checked) -> _Data:
    """Step 1: the checked split (:func:`check`), the tool override applied."""
    opts, train_rows, test_rows = checked.options, checked.train_rows, checked.test_rows
    layout = ParamLayout(samples.anchor_ids)
    model = with_tool(model, opts.tool_mm)
    data = _Data(
        model,
        layout,
        samples,
        model.table_rad(samples.joints_deg),
        samples.anchor_index(),
        train_rows,
        test_rows,
    )
    for k, aid in enumerate(layout.anchors):
        if not np.any(data.aidx == k):
            raise SampleError(f"anchor {aid!r} has no training samples", column="anchor")
    return data


def _start_point(
    d: _Data, theta_before: FloatArray, opts: IdentifyOptions
) -> tuple[FloatArray, np.ndarray]:
    """Step 3: the common start (nominal DH, tool and anchors fitted) and the candidate mask."""
    layout = d.layout
    candidates = candidate_mask(layout, opts.identify_tool, opts.fix)
    theta_start = theta_before
    if candidates[N_DH:N_KIN].any():
        free0 = np.zeros(layout.size, dtype=bool)
        free0[N_DH:] = candidates[N_DH:]
        prob = Problem(d.model, layout, d.q, d.length_mm, d.aidx, free0, theta_before)
        theta_start = plain_fit(prob)
    return theta_start, candidates


def _free_set(
    d: _Data, theta_start: FloatArray, candidates: np.ndarray, opts: IdentifyOptions
) -> tuple[Identifiability, np.ndarray]:
    """Step 4: identifiability at the start, and the solved set (base set, ± names)."""
    layout = d.layout
    _, jac = length_jacobian(d.model, theta_start, d.q, d.aidx)
    generic = generic_jacobian(d.model, layout, theta_start)
    plausible = methods.internal_sigma(layout, opts.prior_mm, opts.prior_deg, np.inf)
    ident = analyse(
        jac,
        layout.names,
        candidates,
        rtol=opts.rtol,
        structural_jacobian=generic,
        noise_mm=opts.noise_mm if opts.noise_rank else None,
        plausible=plausible,
    )
    free = solved_mask(layout, ident.base, candidates, opts.free)
    # validate() checked the bound before any fit; this checks the count on these data.
    check_training_rows(d.train_rows.size, len(d.samples), int(np.count_nonzero(free)))
    return ident, free


def _problem(d: _Data, theta_start: FloatArray, free: np.ndarray, opts: PriorOptions) -> Problem:
    """The problem the method solves: ML, or MAP with a Gaussian prior toward the nominal."""
    # noise_mm also sizes the filters' measurement noise, with or without the prior.
    ml = Problem(
        d.model,
        d.layout,
        d.q,
        d.length_mm,
        d.aidx,
        free,
        theta_start,
        noise_mm=opts.noise_mm,
        drift_basis=d.drift_basis,
    )
    return prior.with_prior(ml, opts)


def _weighed_solve(
    d: _Data,
    samples: SampleSet,
    theta_start: FloatArray,
    free: np.ndarray,
    opts: IdentifyOptions,
    progress: ProgressFn | None,
    clock: Clock | None,
) -> tuple[PriorOptions, dict[str, Any], robust.Solved]:
    """Step 5: the fit, its prior weighed as ``prior_weight`` says
    (:func:`calib.prior.weighed_solve`; ``cv`` scores each fold by an identification)."""
    settings, robust_opts = part(opts, SolverSettings), part(opts, RobustOptions)

    def fit(problem: Problem) -> robust.Solved:
        def once(p: Problem, x0: FloatArray, cb: ProgressFn | None) -> Any:
            return methods.run(p, x0, settings, cb, clock)

        return robust.solve(problem, robust_opts, once, progress)

    def held_out_rmse(p: PriorOptions, tr: np.ndarray, te: np.ndarray) -> float:
        # A fold of the prior's cross-validation: plain LM without the robust step (the
        # folds rank prior scales; the final fit deals with outliers), on the given rows.
        fold = with_part(replace(opts, method="lm", test_fraction=0.0, robust="none"), p)
        res = identify(d.model, samples, fold, train_rows=tr, test_rows=te)
        return float(res.metrics["after"]["test"]["rmse_mm"])

    # Randomly held-out rows are rows like the training rows: their prediction errors tell
    # the noise too (prior.noise_from_map). Grouped hold-out keeps whole pose groups away on
    # purpose; their errors include the extrapolation, so they stay out of it.
    test = d.test_rows
    held_out = (
        prior.HeldOutRows(
            d.q_all[test], np.asarray(d.samples.length_mm[test], float), d.aidx_all[test]
        )
        if test.size and opts.holdout == "random"
        else None
    )
    return prior.weighed_solve(
        lambda o: _problem(d, theta_start, free, o),
        theta_start,
        part(opts, PriorOptions),
        fit,
        held_out_rmse,
        lambda: pose_groups(samples, opts.n_groups)[d.train_rows],
        d.train_rows,
        progress,
        held_out,
    )


def _counting(progress: ProgressFn | None) -> ProgressFn | None:
    """``progress`` with ``iteration``: the solvers' whole iterations (the calls that carry a
    ``cost_rms_mm``) numbered 1, 2, … over the whole fit, every stage and round."""
    if progress is None:
        return None
    outer, count = progress, [0]

    def counted(
        f: float, msg: str, /, *, cost_rms_mm: float | None = None, iteration: int | None = None
    ) -> None:
        if cost_rms_mm is not None:
            count[0] += 1
        outer(f, msg, cost_rms_mm=cost_rms_mm, iteration=count[0] if count[0] else None)

    return counted


def _select_drift(
    d: _Data, theta_start: FloatArray, free: np.ndarray, opts: DriftOptions, p: PriorOptions
) -> drift.Selection | None:
    """Step 4b: the drift model (:func:`calib.drift.select_at_plain_fit`) at a plain MAP (or
    ML) fit with the options' noise; sets ``d.drift_model`` and ``d.drift_basis`` unless it
    is none."""
    if opts.drift == "none" or opts.method not in drift.DRIFT_METHODS:
        return None
    t_all, unit = d.times
    t = t_all[d.train_rows]
    sel, units = drift.select_at_plain_fit(
        opts.drift,
        _problem(d, theta_start, free, p),
        t,
        d.train_rows,
        lambda th: d.units(th, d.train_rows),
        unit,
    )
    if not sel.model.is_none:
        d.drift_model = sel.model
        d.drift_basis = sel.model.basis(t, units)
    return sel


def _drift_mm(d: _Data, theta: FloatArray, beta: FloatArray, rows: np.ndarray) -> FloatArray:
    """The drift terms (r,) [mm] at ``rows`` (interpolated at their times) under ``theta``."""
    if d.drift_model is None or rows.size == 0:
        return np.zeros(rows.size)
    basis = d.drift_model.basis(d.times[0][rows], d.units(theta, rows))
    return np.asarray(basis @ beta, dtype=float)


def _figures(
    d: _Data, theta_before: FloatArray, theta: FloatArray, beta: FloatArray
) -> dict[str, dict[str, dict[str, float]]]:
    """Length metrics before and after, on the training and the test rows; the after figures
    with the drift terms ``beta`` (m,) [mm] at each row's time (none before)."""
    return length_figures(
        d.samples.length_mm,
        {"train": d.train_rows, "test": d.test_rows},
        {
            "before": lambda rows: d.lengths(theta_before, rows),
            "after": lambda rows: d.lengths(theta, rows) + _drift_mm(d, theta, beta, rows),
        },
    )


def identify(
    model: RobotModel,
    samples: SampleSet,
    options: IdentifyOptions | None = None,
    *,
    train_rows: np.ndarray | None = None,
    test_rows: np.ndarray | None = None,
    progress: ProgressFn | None = None,
    clock: Clock | None = None,
) -> IdentifyResult:
    """Identify the calibrated model from samples (the six steps of the module docstring).

    Parameters
    ----------
    model : RobotModel
        Nominal model.
    samples : SampleSet
        ``n`` samples: joints (n, 6) [deg], lengths (n,) [mm], anchor ids.
    options : IdentifyOptions
    train_rows, test_rows : ndarray of int, optional
        Explicit split; overrides ``options.test_fraction``.
    progress : callable(fraction, message), optional
        May raise :class:`calib.solvers.common.Cancelled` to stop.
    clock : callable() -> float [s], optional
        Times the run for ``elapsed_s`` (and the solver's); the caller injects it (e.g.
        ``time.perf_counter``), calib reads no clock. None: not timed, 0.

    Raises
    ------
    SampleError
        Joint angles outside the model's limits, too few samples, an anchor with too few
        samples. Nothing is partially returned.
    calib.options.OptionError
        A bad option, or unknown parameter names in ``fix``/``free`` (a ``ValueError``).
    """
    validate_joint_limits(samples, model)
    checked = check(model, samples, options, train_rows, test_rows)
    return _run(model, samples, checked, progress, clock)


def identify_checked(
    model: RobotModel,
    samples: SampleSet,
    checked: Checked,
    *,
    progress: ProgressFn | None = None,
    clock: Clock | None = None,
) -> IdentifyResult:
    """:func:`identify` on options :func:`check` has checked against these ``samples`` and
    ``model`` (they are not checked again; the joint limits are).

    Raises
    ------
    SampleError
        Joint angles outside the model's limits, an anchor without training samples.
    """
    validate_joint_limits(samples, model)
    return _run(model, samples, checked, progress, clock)


def _run(
    model: RobotModel,
    samples: SampleSet,
    checked: Checked,
    progress: ProgressFn | None,
    clock: Clock | None,
) -> IdentifyResult:
    """Steps 2 to 6 on checked options and samples."""
    opts = checked.options
    progress = _counting(progress)
    timer = Timer(clock)
    d = _prepare(model, samples, checked)
    layout = d.layout
    report(progress, 0.0, "fitting the anchor with the nominal model")
    theta_before = fit_anchors(d.model, layout, np.zeros(layout.size), d.q, d.aidx, d.length_mm)
    theta_start, candidates = _start_point(d, theta_before, opts)
    report(progress, 0.05, "identifiability analysis")
    ident, free = _free_set(d, theta_start, candidates, opts)
    report(progress, 0.06, "testing for drift and steps of the measurement")
    selection = _select_drift(
        d, theta_start, free, part(opts, DriftOptions), part(opts, PriorOptions)
    )
    used, prior_detail, solved = _weighed_solve(
        d, samples, theta_start, free, opts, progress, clock
    )
    notes: list[str] = []
    if used.prior:
        notes.append(
            f"MAP prior toward the nominal model: {used.prior_mm} mm / {used.prior_deg} deg "
            f"per DH error, noise {used.noise_mm:.3g} mm"
        )
    result, final = solved.result, solved.problem
    if opts.robust != "none":
        notes.append(robust_note(opts, solved, d.train_rows.size, len(d.samples)))
    report(progress, 0.96, "covariance and metrics")

    x = result.x
    theta = final.full(x)
    beta = final.drift_coefficients(x)
    drift_block = None
    if opts.drift != "none":
        drift_block = drift_report(
            d.drift_model or drift.DriftModel(time_unit=d.times[1]), beta, selection, opts.drift
        )
        every = np.arange(len(samples))
        drift_block["per_sample_mm"] = _drift_mm(d, theta, beta, every).tolist()
        drift_block["rows_flagged"] = [int(d.train_rows[i]) for i in solved.flagged]
        if opts.method not in drift.DRIFT_METHODS:
            drift_block["note"] = f"not modelled: method {opts.method} does not support it"
        # The one wording of what was found: the CLI, the HTML report and the page read it.
        drift_block["summary"] = drift_summary(drift_block)
    cov, _ = covariance(final, x)
    sigma, corr = uncertainty(final, x, cov)
    # The covariance propagated to the tool point over a workspace sample within the joint
    # limits, after removing the rigid motions distances cannot see (calib.tcp).
    tcp = tcp_uncertainty_for_problem(final, x, cov).to_dict()
    extension = (
        d.lengths(theta, np.arange(len(samples))) - theta[N_KIN:].reshape(-1, 4)[d.aidx_all, 3]
    )
    plaus = plausibility(layout, theta, d.model.tool_mm, extension)
    if not plaus["plausible"]:
        notes.append(implausibility_advice(layout, final.free_names, sigma, cov, plaus, opts))
    flagged = [int(d.train_rows[i]) for i in solved.flagged]
    report(progress, 1.0, "done")
    return IdentifyResult(
        model=d.model,
        layout=layout,
        method=opts.method,
        theta=theta,
        theta_before=theta_before,
        free_names=[n for n, f in zip(layout.names, free, strict=True) if f],
        sigma=sigma,
        correlation=corr,
        identifiability=ident,
        solver=result,
        metrics=_figures(d, theta_before, theta, beta),
        flagged_rows=flagged,
        train_rows=d.train_rows,
        test_rows=d.test_rows,
        options=opts,
        plausibility=plaus,
        notes=notes,
        elapsed_s=timer.elapsed(),
        theta_start=theta_start,
        tcp_uncertainty_mm=tcp,
        prior=prior_block(part(opts, PriorOptions), used, prior_detail),
        robust_detail=robust_detail(opts, solved),
        drift=drift_block,
    )
