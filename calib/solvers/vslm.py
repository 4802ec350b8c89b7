"""Variable step-size Levenberg–Marquardt, the paper's eq. (15) (M8, and the second stage of M9).

The paper's update is ::

    X_{t+1} = X_t + δ_t (JᵀJ + λI)⁻¹ Jᵀ E,       δ_{t+1} = μ δ_t,   δ_0 = 0.8, μ = 0.95

**Where the paper is ill-posed, and what this implementation does instead.**

1. *The step size vanishes whether or not the iterate has converged.* ``Σ_t δ_t = δ_0/(1 − μ)
   = 16`` full steps at most, so after a few dozen iterations the updates are numerically zero
   and the method "converges" (its Fig. 6) wherever it happens to be. Here, when ``δ_t`` falls
   below ``delta_min`` while the convergence tests are unmet, the schedule restarts at ``δ_0``
   (a restart schedule keeps the decaying character but cannot freeze). Convergence is judged
   on the *undamped* problem — the scaled gradient ``‖(JD⁻¹)ᵀr‖∞ ≤ gtol‖r‖`` or the predicted
   reduction of the full (δ = 1) step relative to the cost — never on the size of δ.
2. *λI mixes millimetres and radians.* The damping acts on the column-scaled problem
   (``J D⁻¹``, ``D`` = running column norms), so ``λ`` is unit-free.
3. *No step acceptance.* A fixed-λ step can increase the cost on ill-conditioned problems. A
   step that does not decrease the cost is rejected and λ is multiplied by 10; after an
   accepted step λ relaxes back toward its initial value (never below it), as in LM.
4. *Normal equations.* ``(JᵀJ + λI)⁻¹`` squares the condition number (1e10 → 1e20 on the real
   data). The step is computed from the SVD of ``J D⁻¹``, which is exact to rounding.
5. The sign: with ``E = Z − Z'`` (measured minus model) and ``J = ∂Z'/∂X``, the update is
   ``+δ(JᵀJ+λI)⁻¹JᵀE``; in this code the residual is ``r = Z' − Z = −E``, hence ``h = −…Jᵀr``.

With these changes the fixed point is the same stationary point as LM's (``Jᵀr = 0``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.kinematics import FloatArray
from calib.problem import Problem
from calib.solvers.common import (
    ProgressFn,
    SolverResult,
    Timer,
    column_scale,
    damped_step,
    report,
)


@dataclass(frozen=True)
class VSLMOptions:
    """Options of :func:`solve` (``delta0`` and ``mu`` are the paper's 0.8 and 0.95)."""

    delta0: float = 0.8
    mu: float = 0.95
    delta_min: float = 0.2
    lam: float = 1e-6  # unit-free damping relative to the largest squared singular value
    max_iterations: int = 500
    gtol: float = 1e-10
    ftol: float = 1e-12
    max_rejections: int = 30

    def __post_init__(self) -> None:
        if not 0.0 < self.delta0 <= 1.0:
            raise ValueError(f"delta0 must be in (0, 1], got {self.delta0}")
        if not 0.0 < self.mu < 1.0:
            raise ValueError(f"mu must be in (0, 1), got {self.mu}")
        if not 0.0 < self.delta_min <= self.delta0:
            raise ValueError(f"delta_min must be in (0, delta0], got {self.delta_min}")


def solve(
    problem: Problem,
    x0: FloatArray | None = None,
    options: VSLMOptions | None = None,
    progress: ProgressFn | None = None,
    method: str = "vslm",
) -> SolverResult:
    """Run VSLM from ``x0`` (shape (k,)); see the module docstring for the corrections."""
    opts = options or VSLMOptions()
    timer = Timer()
    x = problem.x0() if x0 is None else np.array(x0, dtype=float)
    res, jac = problem.residuals_and_jacobian(x)
    cost = 0.5 * float(res @ res)
    history = [problem.data_rms_mm(x)]
    if not np.isfinite(cost):
        return SolverResult(method, x, False, -1, "non-finite residual at the start", 0, history)
    scale = column_scale(jac)
    delta = opts.delta0
    lam0: float | None = None
    lam = 0.0
    status, message = 0, "iteration limit reached"
    it = 0
    for it in range(1, opts.max_iterations + 1):
        js = jac / scale
        grad = js.T @ res
        if np.max(np.abs(grad)) <= opts.gtol * np.sqrt(2.0 * cost):
            status, message, it = 1, "gradient below gtol", it - 1
            break
        u, s, vt = np.linalg.svd(js, full_matrices=False)
        if lam0 is None:
            lam0 = opts.lam * float(s[0] ** 2)
            lam = lam0
        full_step = damped_step(u, s, vt, res, lam)
        predicted_full = 0.5 * float(full_step @ (lam * full_step - grad))
        if predicted_full <= opts.ftol * cost:
            status, message, it = 2, "predicted reduction of the full step below ftol", it - 1
            break
        accepted = False
        for _ in range(opts.max_rejections):
            h = delta * damped_step(u, s, vt, res, lam)
            x_new = x + h / scale
            res_new = problem.residuals(x_new)
            cost_new = 0.5 * float(res_new @ res_new)
            if np.isfinite(cost_new) and cost_new < cost:
                x, cost, res = x_new, cost_new, res_new
                res, jac = problem.residuals_and_jacobian(x)
                scale = column_scale(jac, scale)
                lam = max(lam0, lam / 10.0)
                accepted = True
                break
            lam *= 10.0
        history.append(problem.data_rms_mm(x))
        report(progress, it / opts.max_iterations, f"{method} iteration {it}, step {delta:.3f}")
        if not accepted:
            status, message = 3, "no decrease possible at any damping (converged to precision)"
            break
        delta *= opts.mu
        if delta < opts.delta_min:
            delta = opts.delta0
    return SolverResult(
        method=method,
        x=x,
        success=status > 0,
        status=status,
        message=message,
        iterations=it,
        cost_history_rms_mm=history,
        elapsed_s=timer.elapsed(),
    )
