"""Robust weighting for iteratively reweighted least squares: one small function per mode.

Each weight function maps standardised residuals ``u = |t| / s``, shape (n,), to IRLS weights
of the same shape, given the threshold ``k`` in robust standard deviations. ``t`` are the
residuals studentised by their leverage (:func:`studentised`): a fitted row's residual has
variance ``σ²(1 − h)``, an excluded row's prediction error ``σ²(1 + h)``; ``s`` is 1.4826 × the
median absolute deviation of ``t``, so ``s`` estimates the noise σ itself, not the smaller
spread of the fitted residuals. :data:`WEIGHTS` is the table ``robust`` option name → weight
function, as scipy's ``least_squares`` keeps its losses.

``auto`` (the default) and ``reject`` share one loop in :mod:`calib.identify`: a plain fit;
rows beyond the threshold get weight 0 and the method refits *from the start* (not from the
contaminated solution); repeat until the rejected set is stable. ``auto`` uses the threshold
:func:`auto_threshold`, which grows with ``n`` so that clean Gaussian data have a 1 % chance
of any flag at all: on clean data ``auto`` returns the plain fit itself.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy.stats import norm

from calib.kinematics import FloatArray

#: Family-wise false-flag probability of ``auto`` on clean Gaussian data (all ``n`` rows).
AUTO_FALSE_FLAG_PROBABILITY = 0.01

WeightFn = Callable[[FloatArray, float], FloatArray]


def _none(u: FloatArray, k: float) -> FloatArray:
    return np.ones_like(u)


def _huber(u: FloatArray, k: float) -> FloatArray:
    return np.where(u <= k, 1.0, k / np.maximum(u, 1e-300))


def _soft_l1(u: FloatArray, k: float) -> FloatArray:
    return np.asarray(1.0 / np.sqrt(1.0 + (u / k) ** 2))


def _reject(u: FloatArray, k: float) -> FloatArray:
    return (u <= k).astype(float)


#: ``robust`` mode → weight function ``(u, k) -> w``. ``reject`` and ``auto`` are called with
#: their rejection threshold as ``k`` (samples beyond it get weight 0), the others with
#: ``robust_k``.
WEIGHTS: dict[str, WeightFn] = {
    "none": _none,
    "huber": _huber,
    "soft_l1": _soft_l1,
    "reject": _reject,
    "auto": _reject,
}

#: Modes that reject rows (weight 0) and refit from the start, rather than reweight.
REJECTING = ("reject", "auto")


def auto_threshold(n: int, flag_threshold: float) -> float:
    """Rejection threshold of ``auto`` [robust σ] for ``n`` rows: at least ``flag_threshold``,
    and at least the two-sided Gaussian quantile at which ``n`` clean rows have a
    :data:`AUTO_FALSE_FLAG_PROBABILITY` chance of any flag (3.9 at n = 100, 4.8 at 2000)."""
    return max(flag_threshold, float(norm.isf(AUTO_FALSE_FLAG_PROBABILITY / (2 * max(n, 1)))))


def threshold(mode: str, n: int, flag_threshold: float) -> float:
    """The flag threshold [robust σ] of ``mode`` for ``n`` rows."""
    return auto_threshold(n, flag_threshold) if mode == "auto" else flag_threshold


def studentised(res: FloatArray, jac: FloatArray, w: FloatArray) -> FloatArray:
    """Residuals divided by their leverage factor, shape (n,) [mm].

    ``res`` (n,) unweighted residuals [mm]; ``jac`` (n, k) their Jacobian in the free
    parameters; ``w`` (n,) the weights of the fit. With ``g_i = j_i (JᵀWJ)⁺ j_iᵀ`` a row in the
    fit (``w_i > 0``) is divided by ``sqrt(1 − w_i g_i)``, an excluded row by ``sqrt(1 + g_i)``.
    """
    norms = np.linalg.norm(jac, axis=0)
    js = jac / np.where(norms > 0, norms, 1.0)
    _, sv, vt = np.linalg.svd(np.sqrt(w)[:, None] * js, full_matrices=False)
    keep = sv > sv.max(initial=0.0) * 1e-10
    proj = (js @ vt[keep].T) / sv[keep]
    g = np.sum(proj * proj, axis=1)
    factor = np.where(w > 0, 1.0 - w * g, 1.0 + g)
    return np.asarray(res / np.sqrt(np.clip(factor, 1e-6, None)))


def standardised(res: FloatArray) -> FloatArray:
    """``|r| / s``, shape (n,), with ``s`` = 1.4826 MAD of ``res`` [mm] (at least 1e-6 mm)."""
    med = np.median(res)
    scale = max(1.4826 * np.median(np.abs(res - med)), 1e-6)
    return np.asarray(np.abs(res) / scale)


def weights(
    mode: str, res: FloatArray, k: float, flag_threshold: float
) -> tuple[FloatArray, FloatArray]:
    """IRLS weights and standardised residuals, both shape (n,), for residuals ``res`` [mm]
    (studentised already, :func:`studentised`, when the caller has the Jacobian).
    ``flag_threshold`` is the rejecting modes' threshold (:func:`threshold`)."""
    u = standardised(res)
    return WEIGHTS[mode](u, flag_threshold if mode in REJECTING else k), u
