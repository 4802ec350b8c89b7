"""Small linear-algebra helpers shared by the problem's variable projection
(:class:`calib.problem.Problem`) and the drift model's choice (:mod:`calib.drift`)."""

from __future__ import annotations

import numpy as np

from calib.kinematics import FloatArray


def coefficients(basis_w: FloatArray, residual_w: FloatArray) -> FloatArray:
    """``β`` (m,) [mm] minimising ``‖residual_w − basis_w β‖`` (weighted rows, (n, m) and (n,))."""
    if basis_w.shape[1] == 0:
        return np.zeros(0)
    beta, *_ = np.linalg.lstsq(basis_w, residual_w, rcond=1e-10)
    return np.asarray(beta, dtype=float)


def orthonormal(mat: FloatArray, rtol: float = 1e-10) -> FloatArray:
    """Orthonormal basis (n, r) of the column span of ``mat`` (n, m) (SVD, rank cut ``rtol``)."""
    if mat.shape[1] == 0:
        return np.zeros((mat.shape[0], 0))
    norms = np.linalg.norm(mat, axis=0)
    norms[norms == 0] = 1.0
    u, s, _ = np.linalg.svd(mat / norms, full_matrices=False)
    if s.size == 0 or not s[0] > 0:
        return np.zeros((mat.shape[0], 0))
    return np.asarray(u[:, s > s[0] * rtol], dtype=float)
