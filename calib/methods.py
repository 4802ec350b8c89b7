"""The identification methods: a registry name → (solver options type, options builder, solve).

Each entry turns the method's group of the options (:class:`calib.options.SolverSettings`)
into the solver's own options and runs the solver with a common signature
``solve(problem, x0, solver_options, settings, progress)``. A new method is one more entry here
(and its name in :data:`calib.options.Method`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from calib.cable import N_DH, ParamLayout
from calib.kinematics import FloatArray
from calib.options import METHODS, SolverSettings
from calib.problem import Problem
from calib.solvers import de, ekf, geolm, lm, ukf, ukf_vslm, vslm
from calib.solvers.common import ProgressFn, SolverResult
from calib.timing import Clock, Timer

SolveFn = Callable[[Problem, FloatArray, Any, SolverSettings, "ProgressFn | None"], SolverResult]

#: The filters' initial 1σ [mm] of a parameter the prior leaves unbounded (the tool point
#: without ``prior_tool_mm``, every anchor's ``P0`` and zero offset): the spread the filters
#: give those parameters without a prior at the default ``filter_sigma_mm`` (5 mm ×
#: :data:`START_FITTED_SPREAD`), so turning the prior on changes only the spreads it sets.
UNBOUNDED_SPREAD_MM = 20.0
#: The same for a DH angle the prior leaves unbounded [deg]; identify's prior bounds every DH
#: parameter, so only a problem built with another prior reaches it: twice the default
#: ``filter_sigma_deg``.
UNBOUNDED_SPREAD_DEG = 1.0
#: Without a prior, the filters start the tool point and the anchors this many times wider
#: than the DH lengths (``filter_sigma_mm``): identify's start fitted them under the nominal
#: DH table (its step 3), so their error also holds what the DH errors project onto them.
START_FITTED_SPREAD = 4
#: Half-widths of DE's search box around the start, per DH length [mm] and DH angle [deg]:
#: half the largest plausible DH error (:data:`calib.identify.plausibility.PLAUSIBLE_DH_MM`
#: 10 mm, :data:`calib.identify.plausibility.PLAUSIBLE_DH_DEG` 1 deg), around a start that is
#: the nominal table.
DE_BOX_DH_MM = 5.0
DE_BOX_DH_DEG = 0.5
#: Half-width of DE's box for the tool point and the anchors [mm]: ten times the DH box, as
#: their start is a fit that carries the DH errors' projection (:data:`START_FITTED_SPREAD`).
DE_BOX_FITTED_MM = 50.0


@dataclass(frozen=True)
class MethodEntry:
    """One method: its solver's options type, how to build them, and how to run it."""

    options_type: type
    make_options: Callable[[SolverSettings], Any]
    solve: SolveFn


def internal_sigma(layout: ParamLayout, mm: float, deg: float, other_mm: float) -> FloatArray:
    """Scale per parameter (p,): DH lengths ``mm``, DH angles ``deg`` (rad), rest ``other_mm``."""
    out = np.full(layout.size, float(other_mm))
    out[:N_DH] = mm
    out[layout.is_angle] = np.deg2rad(deg)
    return out


def initial_covariance(problem: Problem, opts: SolverSettings) -> FloatArray:
    """The filters' ``P0``, shape (k, k): the prior's spread, else the ``filter_sigma_*``."""
    layout, free = problem.layout, problem.free
    if problem.has_prior:
        assert problem.prior_sigma is not None
        spread = np.where(
            np.isfinite(problem.prior_sigma),
            problem.prior_sigma,
            internal_sigma(layout, UNBOUNDED_SPREAD_MM, UNBOUNDED_SPREAD_DEG, UNBOUNDED_SPREAD_MM),
        )[free]
    else:
        spread = internal_sigma(
            layout,
            opts.filter_sigma_mm,
            opts.filter_sigma_deg,
            START_FITTED_SPREAD * opts.filter_sigma_mm,
        )[free]
    return np.diag(spread**2)


def _ukf_options(opts: SolverSettings, default: ukf.UKFOptions) -> ukf.UKFOptions:
    batch = default.batch_size if opts.ukf_batch_size is None else opts.ukf_batch_size
    return ukf.UKFOptions(epochs=opts.ukf_epochs, batch_size=batch, ramp=default.ramp)


def _vslm_options(opts: SolverSettings) -> vslm.VSLMOptions:
    return vslm.VSLMOptions(delta0=opts.vslm_delta0, mu=opts.vslm_mu)


def _ekf_options(opts: SolverSettings) -> ekf.EKFOptions:
    batch = ekf.EKFOptions().batch_size if opts.ukf_batch_size is None else opts.ukf_batch_size
    return ekf.EKFOptions(epochs=opts.ukf_epochs, batch_size=batch)


def _ukf_vslm_options(opts: SolverSettings) -> ukf_vslm.UKFVSLMOptions:
    stage1 = _ukf_options(opts, ukf_vslm.UKFVSLMOptions().ukf)
    return ukf_vslm.UKFVSLMOptions(ukf=stage1, vslm=_vslm_options(opts))


def _geolm_options(opts: SolverSettings) -> geolm.GeoLMOptions:
    return geolm.GeoLMOptions(ukf=_ukf_options(opts, geolm.GeoLMOptions().ukf))


def _de_solve(
    problem: Problem,
    x0: FloatArray,
    solver: de.DEOptions,
    opts: SolverSettings,
    progress: ProgressFn | None,
) -> SolverResult:
    bounds = internal_sigma(problem.layout, DE_BOX_DH_MM, DE_BOX_DH_DEG, DE_BOX_FITTED_MM)
    bounds = bounds[problem.free]
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
    opts: SolverSettings,
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
