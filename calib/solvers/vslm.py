"""Variable step-size Levenberg–Marquardt, the paper's eq. (15) (M8, and the second stage of M9).

The paper's update is ::

    X_{t+1} = X_t + δ_t (JᵀJ + λI)⁻¹ Jᵀ E,       δ_{t+1} = μ δ_t,   δ_0 = 0.8, μ = 0.95

**Where the paper is ill-posed, and what this implementation does instead.**

1. *The step size vanishes whether or not the iterate has converged.* ``Σ_t δ_t = δ_0/(1 − μ)
   = 16`` full steps at most, so after a few dozen iterations the updates are numerically zero
   and the method "converges" (its Fig. 6) wherever it happens to be. Here, when ``δ_t`` falls
   below ``delta_min`` while the convergence tests are unmet, the schedule restarts at ``δ_0``
   (a restart schedule keeps the decaying character but cannot freeze). Convergence is judged
   on the full (δ = 1) step, never on the size of δ; see 6.
2. *λI mixes millimetres and radians, and λ is not given.* The damping acts on the
   column-scaled problem (``J D⁻¹``, ``D`` = running column norms), so ``λ`` is unit-free; it
   starts at ``lam · s_max²`` with ``lam = 1e-10``. A larger λ is not harmless: a direction
   with singular value ``s`` converges at the rate ``1 − δ s²/(s² + λ)`` per iteration, and
   a scaled Jacobian with directions at ``s²`` far below ``s_max²`` (the synthetic
   benchmark's has some) converges there only slowly with a larger ``lam``. Ill-conditioned
   data are protected by the step acceptance (3), which raises λ when a step fails.
3. *No step acceptance.* A fixed-λ step can increase the cost on ill-conditioned problems. A
   step that does not decrease the cost is rejected and λ is multiplied by 10; after an
   accepted step λ relaxes back toward its initial value (never below it), as in LM.
4. *Normal equations.* ``(JᵀJ + λI)⁻¹`` squares the condition number (1e10 → 1e20 on the real
   data). The step is computed from the SVD of the triangular factor of ``[J D⁻¹ | r]``
   (:class:`calib.solvers.common.LinearModel`), which is exact to rounding.
5. The sign: with ``E = Z − Z'`` (measured minus model) and ``J = ∂Z'/∂X``, the update is
   ``+δ(JᵀJ+λI)⁻¹JᵀE``; in this code the residual is ``r = Z' − Z = −E``, hence ``h = −…Jᵀr``.
6. *No stopping test.* The paper runs a fixed ``T9`` iterations. Here the iteration stops when
   the iterate is within ``sigma_tol`` (default 0.001) standard errors of the linearised
   optimum: with ``ΔL`` the cost reduction the full step predicts and ``σ̂² = 2F/(m − k)``,
   ``2ΔL/σ̂²`` is the squared Mahalanobis length of the remaining step under the estimate's own
   covariance (:func:`calib.solvers.common.distance_to_optimum_sigma`). Going further moves
   the parameters by a negligible fraction of their uncertainty. Also: the scaled gradient
   ``‖(JD⁻¹)ᵀr‖∞ ≤ gtol‖r‖`` (noise-free data), and no decrease at any damping.
   Because each step is only a fraction ``δ`` of the full step, the distance shrinks by about
   ``1 − δ`` per iteration: a start within a few standard errors (the UKF's estimate) needs
   about seven iterations (57 with the previous test, a predicted reduction below 1e-12 of
   the cost, and ``lam = 1e-6``).

With these changes the fixed point is the same stationary point as LM's (``Jᵀr = 0``).
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
class VSLMOptions:
    """Options of :func:`solve` (``delta0`` and ``mu`` are the paper's 0.8 and 0.95)."""

    delta0: float = 0.8
    mu: float = 0.95
    delta_min: float = 0.2
    lam: float = 1e-10  # unit-free damping relative to the largest squared singular value
    max_iterations: int = 500
    gtol: float = 1e-10
    sigma_tol: float = 1e-3  # stop within this many standard errors of the optimum
    max_rejections: int = 30

    def __post_init__(self) -> None:
        if not 0.0 < self.delta0 <= 1.0:
            raise ValueError(f"delta0 must be in (0, 1], got {self.delta0}")
        if not 0.0 < self.mu < 1.0:
            raise ValueError(f"mu must be in (0, 1), got {self.mu}")
        if not 0.0 < self.delta_min <= self.delta0:
            raise ValueError(f"delta_min must be in (0, delta0], got {self.delta_min}")
        if not self.sigma_tol >= 0.0:
            raise ValueError(f"sigma_tol must be >= 0, got {self.sigma_tol}")


class _Rule:
    """VSLM's damping and step length: ``λ₀ = lam · s_max²`` at the first iteration, ÷ 10 on
    an accepted step (not below ``λ₀``), × 10 on a refused one; the step scaled by ``δ``, which
    shrinks by ``mu`` per accepted step and restarts at ``delta0`` below ``delta_min``."""

    def __init__(self, opts: VSLMOptions) -> None:
        self.opts = opts
        self.delta = opts.delta0
        self.lam0: float | None = None
        self.lam = 0.0

    def reference_damping(self, lin: LinearModel) -> float:
        if self.lam0 is None:
            self.lam0 = self.opts.lam * float(lin.s[0] ** 2)
            self.lam = self.lam0
        return self.lam0

    def attempt(
        self, gn: GaussNewton, lin: LinearModel, grad: FloatArray
    ) -> tuple[bool, Stop | None]:
        lam0 = self.reference_damping(lin)
        for _ in range(self.opts.max_rejections):
            h = self.delta * lin.step(self.lam)
            x_new = gn.x + h / gn.scale
            trial = gn.problem.evaluate(x_new)
            if np.isfinite(trial.cost) and trial.cost < gn.cost:
                gn.accept(x_new, trial)
                self.lam = max(lam0, self.lam / 10.0)
                return True, None
            self.lam *= 10.0
        return False, None

    def note(self) -> str:
        return f", step {self.delta:.3f}"

    def accepted(self, gn: GaussNewton) -> Stop | None:
        self.delta *= self.opts.mu
        if self.delta < self.opts.delta_min:
            self.delta = self.opts.delta0
        return None


@gauss_newton_solver(VSLMOptions, "vslm")
def solve(gn: GaussNewton, opts: VSLMOptions, progress: ProgressFn | None) -> SolverResult:
    """Run VSLM from ``x0`` (shape (k,)); see the module docstring for the corrections.
    Called as ``solve(problem, x0=None, options=None, progress=None, method="vslm")``
    (:func:`calib.solvers.common.gauss_newton_solver`)."""
    return damped_descent(gn, _Rule(opts), opts.max_iterations, opts.gtol, opts.sigma_tol, progress)
