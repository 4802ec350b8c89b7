"""Steps 4b and 5 of an identification: the problem the method solves (ML, or MAP with the
prior), the measurement's drift model chosen at a plain fit (:func:`select_drift`), and the
fit itself, robust, its prior weighed (:func:`weighed_solve`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from calib import drift, methods, prior, robust
from calib.identify.prepared import Prepared
from calib.kinematics import FloatArray
from calib.options import (
    DriftOptions,
    IdentifyOptions,
    PriorOptions,
    RobustOptions,
    SolverSettings,
    part,
)
from calib.problem import Problem
from calib.solvers.common import ProgressFn
from calib.split import pose_groups
from calib.timing import Clock


def make_problem(
    d: Prepared, theta_start: FloatArray, free: np.ndarray, opts: PriorOptions
) -> Problem:
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


def weighed_solve(
    d: Prepared,
    theta_start: FloatArray,
    free: np.ndarray,
    opts: IdentifyOptions,
    progress: ProgressFn | None,
    clock: Clock | None,
    held_out_rmse: prior.HeldOutRmse,
) -> tuple[PriorOptions, dict[str, Any], robust.Solved]:
    """Step 5: the fit, its prior weighed as ``prior_weight`` says
    (:func:`calib.prior.weighed_solve`; ``cv`` scores each fold by ``held_out_rmse``, the
    caller's identification of the fold)."""
    settings, robust_opts = part(opts, SolverSettings), part(opts, RobustOptions)

    def fit(problem: Problem) -> robust.Solved:
        def once(p: Problem, x0: FloatArray, cb: ProgressFn | None) -> Any:
            return methods.run(p, x0, settings, cb, clock)

        return robust.solve(problem, robust_opts, once, progress)

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
        lambda o: make_problem(d, theta_start, free, o),
        theta_start,
        part(opts, PriorOptions),
        fit,
        held_out_rmse,
        lambda: pose_groups(d.samples, opts.n_groups)[d.train_rows],
        d.train_rows,
        progress,
        held_out,
    )


def select_drift(
    d: Prepared, theta_start: FloatArray, free: np.ndarray, opts: DriftOptions, p: PriorOptions
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
        make_problem(d, theta_start, free, p),
        t,
        d.train_rows,
        lambda th: d.units(th, d.train_rows),
        unit,
    )
    if not sel.model.is_none:
        d.drift_model = sel.model
        d.drift_basis = sel.model.basis(t, units)
    return sel
