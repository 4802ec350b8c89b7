"""Robust weighting for iteratively reweighted least squares: one small function per mode.

Each weight function maps standardised residuals ``u = |r| / s`` (``s`` = 1.4826 × the median
absolute deviation of the residuals), shape (n,), to IRLS weights of the same shape, given the
threshold ``k`` in robust standard deviations. :data:`WEIGHTS` is the table ``robust`` option
name → weight function, as scipy's ``least_squares`` keeps its losses.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from calib.kinematics import FloatArray

WeightFn = Callable[[FloatArray, float], FloatArray]


def _none(u: FloatArray, k: float) -> FloatArray:
    return np.ones_like(u)


def _huber(u: FloatArray, k: float) -> FloatArray:
    return np.where(u <= k, 1.0, k / np.maximum(u, 1e-300))


def _soft_l1(u: FloatArray, k: float) -> FloatArray:
    return np.asarray(1.0 / np.sqrt(1.0 + (u / k) ** 2))


def _reject(u: FloatArray, k: float) -> FloatArray:
    return (u <= k).astype(float)


#: ``robust`` mode → weight function ``(u, k) -> w``. ``reject`` is called with the flag
#: threshold as ``k`` (samples beyond it get weight 0), the others with ``robust_k``.
WEIGHTS: dict[str, WeightFn] = {
    "none": _none,
    "huber": _huber,
    "soft_l1": _soft_l1,
    "reject": _reject,
}


def standardised(res: FloatArray) -> FloatArray:
    """``|r| / s``, shape (n,), with ``s`` = 1.4826 MAD of ``res`` [mm] (at least 1e-6 mm)."""
    med = np.median(res)
    scale = max(1.4826 * np.median(np.abs(res - med)), 1e-6)
    return np.asarray(np.abs(res) / scale)


def weights(
    mode: str, res: FloatArray, k: float, flag_threshold: float
) -> tuple[FloatArray, FloatArray]:
    """IRLS weights and standardised residuals, both shape (n,), for residuals ``res`` [mm]."""
    u = standardised(res)
    return WEIGHTS[mode](u, flag_threshold if mode == "reject" else k), u
