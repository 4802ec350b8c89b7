"""Extended Kalman filter for parameter estimation, the paper's M1 (Jiang et al.).

Same structure as :mod:`calib.solvers.ukf` (identity process model, epochs, per-sample updates,
covariance reset to ``P_0`` at every epoch), but the measurement model is linearised with the
analytic Jacobian at the current estimate instead of propagated through sigma points::

    H = ∂L/∂x,  S = H P Hᵀ + R,  K = P Hᵀ S⁻¹,  x ← x + K (L − L(x)),  P ← (I − K H) P
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.cable import length_jacobian
from calib.kinematics import FloatArray, IndexArray
from calib.problem import Problem
from calib.solvers.common import ProgressFn, SolverResult, run_epochs, sample_batches


@dataclass(frozen=True)
class EKFOptions:
    """Options of :func:`solve`."""

    epochs: int = 2
    batch_size: int = 1
    process_noise: float = 1e-8

    def __post_init__(self) -> None:
        if self.epochs < 1:
            raise ValueError(f"epochs must be >= 1, got {self.epochs}")
        if self.batch_size < 1:
            raise ValueError(f"batch_size must be >= 1, got {self.batch_size}")


def solve(
    problem: Problem,
    x0: FloatArray | None = None,
    p0: FloatArray | None = None,
    options: EKFOptions | None = None,
    progress: ProgressFn | None = None,
    method: str = "ekf",
) -> SolverResult:
    """Run the EKF from ``x0`` (shape (k,)) with initial covariance ``p0`` (shape (k, k))."""
    if p0 is None:
        raise ValueError("p0: the EKF needs an initial covariance")
    opts = options or EKFOptions()
    x = problem.x0() if x0 is None else np.array(x0, dtype=float)
    k = x.shape[0]

    def update(
        x: FloatArray, p: FloatArray, rows: IndexArray, r_var: FloatArray
    ) -> tuple[FloatArray, FloatArray]:
        pred, jac_full = length_jacobian(
            problem.model, problem.full(x), problem.q_rad[rows], problem.anchor_index[rows]
        )
        h = jac_full[:, problem.free]
        s_cov = h @ p @ h.T + np.diag(r_var)
        gain = np.linalg.solve(s_cov.T, (p @ h.T).T).T
        x_new = x + gain @ (problem.length_mm[rows] - pred)
        ikh = np.eye(k) - gain @ h
        return x_new, ikh @ p @ ikh.T + gain @ np.diag(r_var) @ gain.T  # Joseph form

    batches = sample_batches(problem.n_samples, opts.batch_size)
    return run_epochs(
        problem, x, p0, opts.epochs, opts.process_noise, batches, update, progress, method
    )
