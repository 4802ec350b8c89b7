"""Differential evolution, the paper's M7 (Zhou et al.), via scipy's ``differential_evolution``.

The cost is ``½‖r(x)‖²`` of the problem (including prior rows when a prior is set). DE needs a
box: each free parameter may move ``±bound`` around the start (``bounds`` in internal units,
shape ``(k,)``), chosen by the caller from plausible error sizes. The population is evaluated
in one vectorised call (parameter sets broadcast through the kinematics).

``polish``: scipy polishes the best member with L-BFGS-B by default. On this problem (columns in
mm and rad, condition numbers of 1e3 and more) L-BFGS-B stops far from the minimum, so scipy's
polish is switched off and the best member is refined with our Levenberg–Marquardt instead —
the same idea (a local method finishes what the global search started), done with the method
suited to a least-squares cost. Its iterations are added to the count.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.kinematics import FloatArray
from calib.problem import Problem
from calib.solvers import lm
from calib.solvers.common import ProgressFn, SolverResult, report


@dataclass(frozen=True)
class DEOptions:
    """Options of :func:`solve` (passed to scipy)."""

    max_generations: int = 300
    popsize: int = 10  # population = popsize · k
    tol: float = 1e-8
    mutation: tuple[float, float] = (0.5, 1.0)
    recombination: float = 0.9
    seed: int = 0
    polish: bool = True


def solve(
    problem: Problem,
    bounds: FloatArray,
    x0: FloatArray | None = None,
    options: DEOptions | None = None,
    progress: ProgressFn | None = None,
    method: str = "de",
) -> SolverResult:
    """Run DE in the box ``x0 ± bounds`` (both shape (k,), internal units)."""
    opts = options or DEOptions()
    start = problem.x0() if x0 is None else np.array(x0, dtype=float)
    half = np.asarray(bounds, dtype=float)
    if half.shape != start.shape or np.any(half <= 0):
        raise ValueError("bounds: need one positive half-width per free parameter")
    history = [problem.data_rms_mm(start)]
    generation = [0]

    def cost(xs: FloatArray) -> FloatArray:
        # scipy passes (k, S) when vectorized
        pred = problem.predict(xs.T)
        data = np.sqrt(problem.weights) * (pred - problem.length_mm)
        total = 0.5 * np.sum(data * data, axis=-1)
        if problem.has_prior:
            assert problem.prior_sigma is not None and problem.prior_mean is not None
            sig = problem.prior_sigma[problem.free]
            pr = problem.noise_mm * (xs.T - problem.prior_mean[problem.free]) / sig
            total = total + 0.5 * np.sum(pr * pr, axis=-1)
        out: FloatArray = np.where(np.isfinite(total), total, 1e300)
        return out

    def callback(intermediate_result: object) -> None:
        generation[0] += 1
        x_best = np.asarray(getattr(intermediate_result, "x", start))
        history.append(problem.data_rms_mm(x_best))
        report(
            progress,
            generation[0] / opts.max_generations,
            f"{method} generation {generation[0]}, rms {history[-1]:.4f} mm",
            history[-1],
        )

    # Imported here: scipy.optimize's import cost, which no other method needs.
    from scipy.optimize import differential_evolution

    res = differential_evolution(
        cost,
        bounds=list(zip(start - half, start + half, strict=True)),
        maxiter=opts.max_generations,
        popsize=opts.popsize,
        tol=opts.tol,
        mutation=opts.mutation,
        recombination=opts.recombination,
        rng=np.random.default_rng(opts.seed),
        polish=False,
        vectorized=True,
        updating="deferred",
        x0=start,
        callback=callback,
    )
    x = np.asarray(res.x, dtype=float)
    history.append(problem.data_rms_mm(x))
    converged = bool(res.success)
    n_iter = int(res.nit)
    message = str(res.message)
    if opts.polish:
        polished = lm.solve(problem, x, method=f"{method}/polish")
        if problem.cost(polished.x) <= problem.cost(x):
            x = polished.x
            history.extend(polished.cost_history_rms_mm[1:])
            n_iter += polished.iterations
            converged = polished.success
            message = f"{message}; LM polish: {polished.message}"
    return SolverResult(
        method=method,
        x=x,
        success=converged,
        status=2 if converged else 0,
        message=message,
        iterations=n_iter,
        cost_history_rms_mm=history,
    )
