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

from calib.kinematics import FloatArray
from calib.solvers.common import (
    GaussNewton,
    LinearModel,
    ProgressFn,
    SolverResult,
    Stop,
    damped_descent,
    gauss_newton_solver,
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


class _Rule:
    """LM's damping (Nielsen): ``λ`` from ``tau · s_max²``, × ``max(1/3, 1 − (2ρ − 1)³)`` on
    an accepted step, × ``ν`` (doubling) on a refused one; stops on ``xtol`` and ``ftol``."""

    def __init__(self, opts: LMOptions) -> None:
        self.opts = opts
        self.lam: float | None = None
        self.nu = 2.0

    def reference_damping(self, lin: LinearModel) -> float:
        return self.opts.sigma_damping * float(lin.s[0] ** 2)

    def attempt(
        self, gn: GaussNewton, lin: LinearModel, grad: FloatArray
    ) -> tuple[bool, Stop | None]:
        opts = self.opts
        if self.lam is None:
            self.lam = opts.tau * float(lin.s[0] ** 2)
        lam = self.lam
        for _ in range(opts.max_rejections):
            h = lin.step(lam)
            z_norm = float(np.linalg.norm(gn.scale * gn.x))
            if np.linalg.norm(h) <= opts.xtol * (z_norm + opts.xtol):
                self.lam = lam
                return False, (3, "step below xtol")
            x_new = gn.x + h / gn.scale
            trial = gn.problem.evaluate(x_new)
            predicted = 0.5 * float(h @ (lam * h - grad))
            rho = (gn.cost - trial.cost) / predicted if predicted > 0 else -1.0
            if np.isfinite(trial.cost) and rho > 0:
                rel = (gn.cost - trial.cost) / max(gn.cost, 1e-300)
                gn.accept(x_new, trial)
                self.lam = lam * max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
                self.nu = 2.0
                if rel <= opts.ftol:
                    return True, (2, "relative cost decrease below ftol")
                return True, None
            lam *= self.nu
            self.nu *= 2.0
        self.lam = lam
        return False, None

    def note(self) -> str:
        return ""

    def accepted(self, gn: GaussNewton) -> Stop | None:
        return None


@gauss_newton_solver(LMOptions, "lm")
def solve(gn: GaussNewton, opts: LMOptions, progress: ProgressFn | None) -> SolverResult:
    """Minimise the problem's residual with Levenberg–Marquardt from ``x0`` (shape (k,)).
    Called as ``solve(problem, x0=None, options=None, progress=None, method="lm")``
    (:func:`calib.solvers.common.gauss_newton_solver`)."""
    return damped_descent(gn, _Rule(opts), opts.max_iterations, opts.gtol, opts.sigma_tol, progress)
