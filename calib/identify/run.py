"""The orchestration of an identification: its steps (:mod:`calib.identify`) in order, on
options checked once (:func:`identify`, or :func:`identify_checked` on
:func:`calib.split.check`'s object).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np

from calib.anchors import fit_anchors
from calib.dataset import SampleSet, validate_joint_limits
from calib.identify.assemble import assemble
from calib.identify.fit import select_drift, weighed_solve
from calib.identify.prepared import prepare
from calib.identify.result_json import IdentifyResult
from calib.identify.start_point import free_set, start_point
from calib.models import RobotModel
from calib.options import (
    METHODS,
    DriftOptions,
    IdentifyOptions,
    PriorOptions,
    part,
    with_part,
)
from calib.solvers.common import ProgressFn, report
from calib.split import Checked, check, pose_groups, split_rows
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


def _fold_rmse(
    model: RobotModel, samples: SampleSet, opts: IdentifyOptions
) -> Callable[[PriorOptions, np.ndarray, np.ndarray], float]:
    """The held-out RMSE [mm] of one fold of the prior's cross-validation
    (:data:`calib.prior.HeldOutRmse`): an identification of ``samples`` by plain LM without
    the robust step (the folds rank prior scales; the final fit deals with outliers), on the
    given training and test rows, under the prior options given."""

    def held_out_rmse(p: PriorOptions, tr: np.ndarray, te: np.ndarray) -> float:
        fold = with_part(replace(opts, method="lm", test_fraction=0.0, robust="none"), p)
        res = identify(model, samples, fold, train_rows=tr, test_rows=te)
        return float(res.metrics["after"]["test"]["rmse_mm"])

    return held_out_rmse


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
    """Identify the calibrated model from samples (the six steps of :mod:`calib.identify`).

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
    d = prepare(model, samples, checked)
    report(progress, 0.0, "fitting the anchor with the nominal model")
    theta_before = fit_anchors(d.model, d.layout, np.zeros(d.layout.size), d.q, d.aidx, d.length_mm)
    theta_start, candidates = start_point(d, theta_before, opts)
    report(progress, 0.05, "identifiability analysis")
    ident, free = free_set(d, theta_start, candidates, opts)
    report(progress, 0.06, "testing for drift and steps of the measurement")
    selection = select_drift(
        d, theta_start, free, part(opts, DriftOptions), part(opts, PriorOptions)
    )
    weighed = weighed_solve(
        d, theta_start, free, opts, progress, clock, _fold_rmse(d.model, samples, opts)
    )
    report(progress, 0.96, "covariance and metrics")
    result = assemble(
        d,
        opts,
        theta_before=theta_before,
        theta_start=theta_start,
        ident=ident,
        free=free,
        selection=selection,
        weighed=weighed,
        timer=timer,
    )
    report(progress, 1.0, "done")
    return result
