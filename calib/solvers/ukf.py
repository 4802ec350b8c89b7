"""Parameter-estimation unscented Kalman filter, the paper's eqs. (8)–(12) (M3, first stage of M9).

The state is the free parameter vector ``x`` (shape ``(k,)``); the process model ``Φ`` of
eq. (8) is the identity (the robot's geometry does not change between samples) with a small
process noise ``Q``; the measurement model ``H`` of eq. (8) maps a parameter vector to the
cable lengths of the samples in the current update. Scaled sigma points (Merwe: ``α, β, κ``)
give the weights ``W_i`` of eqs. (9)–(11); the update is eq. (12). Samples are processed in
order (``batch_size = 1``: one sample per update, as the issue asks; larger batches use the
"current set of observations" ``Y_k`` the paper's eq. (12) speaks of), and the whole set is
swept ``epochs`` times (the paper's ``T3``).

**Where the paper is vague or ill-posed, and what this implementation does.**

- Algorithm 1, line 4, sets the covariance to "a random number" at every epoch. A random
  covariance makes the estimate irreproducible and can be indefinite. Here ``P`` is reset at
  the start of every epoch to the deterministic initial covariance ``P_0`` (built from
  plausible parameter scales), with the previous epoch's estimate as the new mean. Carrying
  ``P`` over instead would count every sample ``epochs`` times and make the filter
  overconfident.
- The sums in eqs. (9)–(11) run over ``i = 0..N+1``, which is not the ``2N + 1`` sigma points an
  unscented transform of an ``N``-dimensional state needs. We use ``2k + 1`` points.
- Eq. (12) writes the covariance update as ``P_k = P_k⁻ − ρ S ρᵀ``; we use the same formula but
  symmetrise it and keep it positive definite (a jitter is added if its Cholesky fails), since
  round-off can make it indefinite after thousands of updates.
- The measurement noise ``R`` is not given; it is ``noise_mm²`` divided by the sample's robust
  weight (a zero weight skips the sample).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.kinematics import FloatArray, IndexArray
from calib.problem import Problem
from calib.solvers.common import ProgressFn, SolverResult, run_epochs, sample_batches


@dataclass(frozen=True)
class UKFOptions:
    """Options of :func:`solve`."""

    epochs: int = 2  # the paper's T3
    batch_size: int = 1  # samples per measurement update
    ramp: bool = False  # batches of 1, 2, 4, … up to batch_size in each epoch
    alpha: float = 0.5
    beta: float = 2.0
    kappa: float = 0.0
    process_noise: float = 1e-8  # Q = process_noise · P0 per update
    shuffle_seed: int | None = None  # None keeps the sample order

    def __post_init__(self) -> None:
        if self.epochs < 1:
            raise ValueError(f"epochs must be >= 1, got {self.epochs}")
        if self.batch_size < 1:
            raise ValueError(f"batch_size must be >= 1, got {self.batch_size}")
        if not 0.0 < self.alpha <= 1.0:
            raise ValueError(f"alpha must be in (0, 1], got {self.alpha}")


def sigma_weights(k: int, opts: UKFOptions) -> tuple[float, FloatArray, FloatArray]:
    """Scale ``γ`` and the mean / covariance weights (shape ``(2k+1,)``) of scaled sigma points."""
    lam = opts.alpha**2 * (k + opts.kappa) - k
    wm = np.full(2 * k + 1, 0.5 / (k + lam))
    wc = wm.copy()
    wm[0] = lam / (k + lam)
    wc[0] = wm[0] + (1.0 - opts.alpha**2 + opts.beta)
    return float(np.sqrt(k + lam)), wm, wc


def _robust_cholesky(p: FloatArray) -> FloatArray:
    jitter = 0.0
    scale = float(np.mean(np.diag(p)))
    for _ in range(8):
        try:
            out = np.linalg.cholesky(p + jitter * np.eye(p.shape[0]))
            return np.asarray(out, dtype=np.float64)
        except np.linalg.LinAlgError:
            jitter = max(jitter * 10.0, 1e-12 * scale)
    raise np.linalg.LinAlgError("covariance is not positive definite even with jitter")


def solve(
    problem: Problem,
    x0: FloatArray | None = None,
    p0: FloatArray | None = None,
    options: UKFOptions | None = None,
    progress: ProgressFn | None = None,
    method: str = "ukf",
) -> SolverResult:
    """Run the UKF.

    Parameters
    ----------
    x0 : ndarray, shape (k,), optional
        Initial estimate (default ``problem.x0()``).
    p0 : ndarray, shape (k, k)
        Initial covariance in internal units (mm², rad²). Required.
    """
    if p0 is None:
        raise ValueError("p0: the UKF needs an initial covariance")
    opts = options or UKFOptions()
    x = problem.x0() if x0 is None else np.array(x0, dtype=float)
    k = x.shape[0]
    gamma, wm, wc = sigma_weights(k, opts)
    rng = None if opts.shuffle_seed is None else np.random.default_rng(opts.shuffle_seed)

    def update(
        x: FloatArray, p: FloatArray, rows: IndexArray, r_var: FloatArray
    ) -> tuple[FloatArray, FloatArray]:
        chol = _robust_cholesky(p)
        sigma = np.empty((2 * k + 1, k))
        sigma[0] = x
        sigma[1 : k + 1] = x + gamma * chol.T
        sigma[k + 1 :] = x - gamma * chol.T
        y_sigma = problem.predict(sigma, rows)  # (2k+1, b), eq. (8)
        x_mean = wm @ sigma  # eq. (9)
        y_mean = wm @ y_sigma  # eq. (10)
        dx = sigma - x_mean
        dy = y_sigma - y_mean
        p_prior = (wc[:, None] * dx).T @ dx
        s_cov = (wc[:, None] * dy).T @ dy + np.diag(r_var)
        p_xy = (wc[:, None] * dx).T @ dy  # eq. (11)
        gain = np.linalg.solve(s_cov.T, p_xy.T).T  # ρ = P_xy S⁻¹
        innovation = problem.length_mm[rows] - y_mean
        x_new = x_mean + gain @ innovation  # eq. (12)
        p_new = p_prior - gain @ s_cov @ gain.T
        return x_new, 0.5 * (p_new + p_new.T)

    batches = sample_batches(problem.n_samples, opts.batch_size, rng, opts.ramp)
    return run_epochs(
        problem,
        x,
        p0,
        opts.epochs,
        opts.process_noise,
        batches,
        update,
        progress,
        method,
        note_every=50,
    )
