"""Levenberg–Marquardt (the paper's M6), done properly.

For ``min ½‖r(x)‖²`` each iteration solves the damped Gauss–Newton system in scaled
coordinates ``z = D x`` (``D`` = running column norms, as in MINPACK)::

    h = argmin ‖J D⁻¹ h + r‖² + λ ‖h‖²

via the SVD of ``J D⁻¹`` (never the normal equations). The gain ratio
``ρ = (F(x) − F(x + h)) / (L(0) − L(h))`` decides: ``ρ > 0`` accepts and shrinks λ by
``max(1/3, 1 − (2ρ − 1)³)``; ``ρ ≤ 0`` rejects and grows λ by ``ν`` (doubling), after Nielsen
(1999) and Madsen, Nielsen & Tingleff, "Methods for non-linear least squares problems" (2004).
Convergence: ``‖(J D⁻¹)ᵀ r‖∞ ≤ gtol ‖r‖`` (the cosine test of MINPACK), a relative cost
decrease ``≤ ftol`` on an accepted step, or
``‖h‖ ≤ xtol (‖D x‖ + xtol)``.
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
class LMOptions:
    """Options of :func:`solve`. Tolerances are relative and unit-free."""

    max_iterations: int = 200
    tau: float = 1e-3  # initial λ relative to the largest squared singular value
    gtol: float = 1e-10
    ftol: float = 1e-12
    xtol: float = 1e-12
    max_rejections: int = 40


def solve(
    problem: Problem,
    x0: FloatArray | None = None,
    options: LMOptions | None = None,
    progress: ProgressFn | None = None,
    method: str = "lm",
) -> SolverResult:
    """Minimise the problem's residual with Levenberg–Marquardt from ``x0`` (shape (k,))."""
    opts = options or LMOptions()
    timer = Timer()
    x = problem.x0() if x0 is None else np.array(x0, dtype=float)
    res, jac = problem.residuals_and_jacobian(x)
    cost = 0.5 * float(res @ res)
    history = [problem.data_rms_mm(x)]
    if not np.isfinite(cost):
        return SolverResult(method, x, False, -1, "non-finite residual at the start", 0, history)
    scale = column_scale(jac)
    lam: float | None = None
    nu = 2.0
    status, message = 0, "iteration limit reached"
    it = 0
    for it in range(1, opts.max_iterations + 1):
        js = jac / scale
        grad = js.T @ res
        if np.max(np.abs(grad)) <= opts.gtol * np.sqrt(2.0 * cost):
            status, message, it = 1, "gradient below gtol", it - 1
            break
        u, s, vt = np.linalg.svd(js, full_matrices=False)
        if lam is None:
            lam = opts.tau * float(s[0] ** 2)
        accepted = False
        for _ in range(opts.max_rejections):
            h = damped_step(u, s, vt, res, lam)
            z_norm = float(np.linalg.norm(scale * x))
            if np.linalg.norm(h) <= opts.xtol * (z_norm + opts.xtol):
                status, message = 3, "step below xtol"
                break
            x_new = x + h / scale
            res_new = problem.residuals(x_new)
            cost_new = 0.5 * float(res_new @ res_new)
            predicted = 0.5 * float(h @ (lam * h - grad))
            rho = (cost - cost_new) / predicted if predicted > 0 else -1.0
            if np.isfinite(cost_new) and rho > 0:
                rel = (cost - cost_new) / max(cost, 1e-300)
                x, cost = x_new, cost_new
                res, jac = problem.residuals_and_jacobian(x)
                scale = column_scale(jac, scale)
                lam *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
                nu = 2.0
                accepted = True
                if rel <= opts.ftol:
                    status, message = 2, "relative cost decrease below ftol"
                break
            lam *= nu
            nu *= 2.0
        history.append(problem.data_rms_mm(x))
        report(progress, it / opts.max_iterations, f"{method} iteration {it}")
        if status:
            break
        if not accepted:
            status, message = 3, "no decrease possible at any damping (converged to precision)"
            break
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
