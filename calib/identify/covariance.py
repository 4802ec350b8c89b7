"""Step 6a of an identification: the covariance of the estimate, and from it every parameter's
1σ and the free parameters' correlation.

Units: internal values in millimetres and radians.
"""

from __future__ import annotations

import numpy as np

from calib.cable import length_jacobian
from calib.kinematics import FloatArray
from calib.problem import Problem


def covariance(problem: Problem, x: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Free-parameter covariance (k, k) in internal units and σ̂ [mm]."""
    pred, jac_full = length_jacobian(
        problem.model, problem.full(x), problem.q_rad, problem.anchor_index
    )
    sw = np.sqrt(problem.weights)
    res = problem.project(sw * (pred - problem.length_mm))  # drift terms profiled out
    jac = problem.project(sw[:, None] * jac_full[:, problem.free])
    k = jac.shape[1]
    dof = max(int(np.count_nonzero(problem.weights > 0)) - k - problem.n_drift, 1)
    sigma2 = max(float(res @ res) / dof, 1e-18)
    d = np.linalg.norm(jac, axis=0)
    d = np.where(d > 0, d, 1.0)
    info = (jac / d).T @ (jac / d) / sigma2
    if problem.has_prior:
        assert problem.prior_sigma is not None
        ps = problem.prior_sigma[problem.free]
        info = info + np.diag(np.where(np.isfinite(ps), 1.0 / (ps * ps), 0.0) / (d * d))
    evals, evecs = np.linalg.eigh(info)
    cutoff = evals.max() * 1e-15
    inv = np.where(evals > cutoff, 1.0 / np.where(evals > cutoff, evals, 1.0), 0.0)
    cov_scaled = (evecs * inv) @ evecs.T
    return cov_scaled / np.outer(d, d), np.array(np.sqrt(sigma2))


def uncertainty(
    problem: Problem, x: FloatArray, cov: FloatArray | None = None
) -> tuple[FloatArray, FloatArray]:
    """1σ per parameter, shape (p,) in internal units (0 for fixed ones), and the correlation
    matrix of the free parameters, shape (k, k), at ``x`` (shape (k,)); ``cov`` is
    :func:`covariance` at ``x`` when the caller has it already."""
    if cov is None:
        cov, _ = covariance(problem, x)
    sig_free = np.sqrt(np.clip(np.diag(cov), 0, None))
    sigma = np.zeros(problem.layout.size)
    sigma[problem.free] = sig_free
    denom = np.outer(sig_free, sig_free)
    corr = np.divide(cov, denom, out=np.zeros_like(cov), where=denom > 0)
    return sigma, corr
