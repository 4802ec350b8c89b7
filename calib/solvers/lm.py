"""Levenberg–Marquardt (the paper's M6), done properly.

For ``min ½‖r(x)‖²`` each iteration solves the damped Gauss–Newton system in scaled
coordinates ``z = D x`` (``D`` = running column norms, as in MINPACK)::

    h = argmin ‖J D⁻¹ h + r‖² + λ ‖h‖²

via the SVD of the triangular factor of ``[J D⁻¹ | r]`` (never the normal equations; see
:class:`calib.solvers.common.LinearModel`). The gain ratio
``ρ = (F(x) − F(x + h)) / (L(0) − L(h))`` decides: ``ρ > 0`` accepts and shrinks λ by
``max(1/3, 1 − (2ρ − 1)³)``; ``ρ ≤ 0`` rejects and grows λ by ``ν`` (doubling), after Nielsen
(1999) and Madsen, Nielsen & Tingleff, "Methods for non-linear least squares problems" (2004).
Convergence: ``‖(J D⁻¹)ᵀ r‖∞ ≤ gtol ‖r‖`` (the cosine test of MINPACK), a relative cost
decrease ``≤ ftol`` on an accepted step, ``‖h‖ ≤ xtol (‖D x‖ + xtol)``, or — the test that
ends most runs on noisy data — the iterate lies within ``sigma_tol`` standard errors of the
linearised optimum (:func:`calib.solvers.common.distance_to_optimum_sigma`, evaluated for the
Gauss–Newton step with a reference damping ``sigma_damping · s_max²`` so that numerically null
directions do not count). It is the same test as VSLM's, so both stop at the same distance
from the same optimum.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.solvers.common import (
    GaussNewton,
    ProgressFn,
    SolverResult,
    gauss_newton_solver,
    report,
)


@dataclass(frozen=True)
class LMOptions:
    """Options of :func:`solve`. Tolerances are relative and unit-free."""

    max_iterations: int = 200
    tau: float = 1e-3  # initial λ relative to the largest squared singular value
    gtol: float = 1e-10
    ftol: float = 1e-12
    xtol: float = 1e-12
    sigma_tol: float = 1e-3  # stop within this many standard errors of the optimum
    sigma_damping: float = 1e-10  # reference damping of that test, relative to s_max²
    max_rejections: int = 40


@gauss_newton_solver(LMOptions, "lm")
def solve(gn: GaussNewton, opts: LMOptions, progress: ProgressFn | None) -> SolverResult:
    """Minimise the problem's residual with Levenberg–Marquardt from ``x0`` (shape (k,)).
    Called as ``solve(problem, x0=None, options=None, progress=None, method="lm")``
    (:func:`calib.solvers.common.gauss_newton_solver`)."""
    problem, method = gn.problem, gn.method
    lam: float | None = None
    nu = 2.0
    status, message = 0, "iteration limit reached"
    it = 0
    for it in range(1, opts.max_iterations + 1):
        linear = gn.linearise(opts.gtol)
        if linear is None:
            status, message, it = 1, "gradient below gtol", it - 1
            break
        lin, grad = linear
        s = lin.s
        stop = gn.within_sigma(lin, opts.sigma_damping * float(s[0] ** 2), opts.sigma_tol)
        if stop is not None:
            status, message, it = 2, stop, it - 1
            break
        if lam is None:
            lam = opts.tau * float(s[0] ** 2)
        accepted = False
        for _ in range(opts.max_rejections):
            h = lin.step(lam)
            z_norm = float(np.linalg.norm(gn.scale * gn.x))
            if np.linalg.norm(h) <= opts.xtol * (z_norm + opts.xtol):
                status, message = 3, "step below xtol"
                break
            x_new = gn.x + h / gn.scale
            trial = problem.evaluate(x_new)
            predicted = 0.5 * float(h @ (lam * h - grad))
            rho = (gn.cost - trial.cost) / predicted if predicted > 0 else -1.0
            if np.isfinite(trial.cost) and rho > 0:
                rel = (gn.cost - trial.cost) / max(gn.cost, 1e-300)
                gn.accept(x_new, trial)
                lam *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
                nu = 2.0
                accepted = True
                if rel <= opts.ftol:
                    status, message = 2, "relative cost decrease below ftol"
                break
            lam *= nu
            nu *= 2.0
        if not accepted:
            gn.history.append(gn.history[-1])
        report(
            progress,
            it / opts.max_iterations,
            f"{method} iteration {it}, rms {gn.history[-1]:.4f} mm",
            gn.history[-1],
        )
        if status:
            break
        if not accepted:
            status, message = 3, "no decrease possible at any damping (converged to precision)"
            break
    return gn.result(status, message, it)
