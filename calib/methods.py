"""The identification methods: a registry name → (solver options type, options builder, solve).

Each entry turns :class:`calib.options.IdentifyOptions` into the solver's own options and runs
the solver with a common signature ``solve(problem, x0, solver_options, options, progress)``.
A new method is one more entry here (and its name in :data:`calib.options.Method`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from calib.cable import N_DH, ParamLayout
from calib.kinematics import FloatArray
from calib.options import METHODS, IdentifyOptions
from calib.problem import Problem
from calib.solvers import de, ekf, geolm, lm, ukf, ukf_vslm, vslm
from calib.solvers.common import ProgressFn, SolverResult
from calib.timing import Clock, Timer

SolveFn = Callable[[Problem, FloatArray, Any, IdentifyOptions, "ProgressFn | None"], SolverResult]


@dataclass(frozen=True)
class MethodEntry:
    """One method: its solver's options type, how to build them, and how to run it."""

    options_type: type
    make_options: Callable[[IdentifyOptions], Any]
    solve: SolveFn


def internal_sigma(layout: ParamLayout, mm: float, deg: float, other_mm: float) -> FloatArray:
    """Scale per parameter (p,): DH lengths ``mm``, DH angles ``deg`` (rad), rest ``other_mm``."""
    out = np.full(layout.size, float(other_mm))
    out[:N_DH] = mm
    out[layout.is_angle] = np.deg2rad(deg)
    return out


def initial_covariance(problem: Problem, opts: IdentifyOptions) -> FloatArray:
    """The filters' ``P0``, shape (k, k): the prior's spread, else the ``filter_sigma_*``."""
    layout, free = problem.layout, problem.free
    if problem.has_prior:
        assert problem.prior_sigma is not None
        spread = np.where(
            np.isfinite(problem.prior_sigma),
            problem.prior_sigma,
            internal_sigma(layout, 20.0, 1.0, 20.0),
        )[free]
    else:
        spread = internal_sigma(
            layout, opts.filter_sigma_mm, opts.filter_sigma_deg, 4 * opts.filter_sigma_mm
        )[free]
    return np.diag(spread**2)


def _ukf_options(opts: IdentifyOptions, default: ukf.UKFOptions) -> ukf.UKFOptions:
    batch = default.batch_size if opts.ukf_batch_size is None else opts.ukf_batch_size
    return ukf.UKFOptions(epochs=opts.ukf_epochs, batch_size=batch, ramp=default.ramp)


def _vslm_options(opts: IdentifyOptions) -> vslm.VSLMOptions:
    return vslm.VSLMOptions(delta0=opts.vslm_delta0, mu=opts.vslm_mu)


def _ekf_options(opts: IdentifyOptions) -> ekf.EKFOptions:
    batch = ekf.EKFOptions().batch_size if opts.ukf_batch_size is None else opts.ukf_batch_size
    return ekf.EKFOptions(epochs=opts.ukf_epochs, batch_size=batch)


def _ukf_vslm_options(opts: IdentifyOptions) -> ukf_vslm.UKFVSLMOptions:
    stage1 = _ukf_options(opts, ukf_vslm.UKFVSLMOptions().ukf)
    return ukf_vslm.UKFVSLMOptions(ukf=stage1, vslm=_vslm_options(opts))


def _geolm_options(opts: IdentifyOptions) -> geolm.GeoLMOptions:
    return geolm.GeoLMOptions(ukf=_ukf_options(opts, geolm.GeoLMOptions().ukf))


def _de_solve(
    problem: Problem,
    x0: FloatArray,
    solver: de.DEOptions,
    opts: IdentifyOptions,
    progress: ProgressFn | None,
) -> SolverResult:
    bounds = internal_sigma(problem.layout, 5.0, 0.5, 50.0)[problem.free]
    return de.solve(problem, bounds, x0, solver, progress)


REGISTRY: dict[str, MethodEntry] = {
    "ukf-vslm": MethodEntry(
        ukf_vslm.UKFVSLMOptions,
        _ukf_vslm_options,
        lambda p, x0, s, o, cb: ukf_vslm.solve(p, x0, initial_covariance(p, o), s, cb),
    ),
    "lm": MethodEntry(
        lm.LMOptions, lambda o: lm.LMOptions(), lambda p, x0, s, o, cb: lm.solve(p, x0, s, cb)
    ),
    "vslm": MethodEntry(
        vslm.VSLMOptions, _vslm_options, lambda p, x0, s, o, cb: vslm.solve(p, x0, s, cb)
    ),
    "ukf": MethodEntry(
        ukf.UKFOptions,
        lambda o: _ukf_options(o, ukf.UKFOptions()),
        lambda p, x0, s, o, cb: ukf.solve(p, x0, initial_covariance(p, o), s, cb),
    ),
    "ekf": MethodEntry(
        ekf.EKFOptions,
        _ekf_options,
        lambda p, x0, s, o, cb: ekf.solve(p, x0, initial_covariance(p, o), s, cb),
    ),
    "de": MethodEntry(
        de.DEOptions,
        lambda o: de.DEOptions(max_generations=o.de_max_generations, seed=o.seed),
        _de_solve,
    ),
    "geolm": MethodEntry(
        geolm.GeoLMOptions,
        _geolm_options,
        lambda p, x0, s, o, cb: geolm.solve(p, x0, s, cb, p0=initial_covariance(p, o)),
    ),
}
assert tuple(REGISTRY) == METHODS, "calib.options.Method and the registry must list the same"


def run(
    problem: Problem,
    x0: FloatArray,
    opts: IdentifyOptions,
    progress: ProgressFn | None,
    clock: Clock | None = None,
) -> SolverResult:
    """Run ``opts.method`` on ``problem`` from ``x0`` (shape (k,)); its ``elapsed_s`` by
    ``clock`` (:data:`calib.timing.Clock`; None: 0, not timed)."""
    entry = REGISTRY[opts.method]
    timer = Timer(clock)
    result = entry.solve(problem, x0, entry.make_options(opts), opts, progress)
    result.elapsed_s = timer.elapsed()
    return result
