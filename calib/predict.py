"""Predict cable lengths from a stored ``result.json`` (the contract of
:meth:`calib.identify.IdentifyResult.to_json`), e.g. to check a calibrated model against
new poses or against an emulated cell's truth."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from calib.conventions import convention_from_mapping
from calib.kinematics import N_JOINTS, FloatArray, forward_position
from calib.result import CalibrationResult, ResultLike


def result_table_rad(result: ResultLike, joints_deg: FloatArray) -> FloatArray:
    """Table angles [rad] of controller joint angles [deg] (shape kept) under the result's
    ``controller`` block (identity when absent; :mod:`calib.conventions`)."""
    convention = convention_from_mapping(CalibrationResult.of(result).controller)
    out: FloatArray = np.deg2rad(convention.to_table_deg(joints_deg))
    return out


def calibrated_dh_internal(result: ResultLike) -> FloatArray:
    """The calibrated DH table of a result, shape (6, 4): ``(alpha_rad, a_mm, d_mm, theta_rad)``.

    Raises
    ------
    ValueError
        ``dh`` is missing or has not six joints.
    """
    table = np.array([r.values() for r in CalibrationResult.of(result).dh_rows()], dtype=float)
    table[:, [0, 3]] = np.deg2rad(table[:, [0, 3]])
    return table


def predict_lengths_from_result(
    result: ResultLike,
    joints_deg: FloatArray | Sequence[Sequence[float]],
    anchor: str | None = None,
) -> FloatArray:
    """Cable lengths the calibrated model predicts: ``L = |p_tcp(q) - P0| + c``.

    Parameters
    ----------
    result : CalibrationResult or mapping
        A result (``dh``, ``convention``, ``tool_mm``, ``anchor_mm``, ``length_offset_mm``,
        ``anchor_id``, ``anchors``).
    joints_deg : ndarray, shape (n, 6)
        Joint angles [deg].
    anchor : str, optional
        Anchor id; default the result's first anchor.

    Returns
    -------
    ndarray, shape (n,)
        Predicted indicator readings [mm].

    Raises
    ------
    ValueError
        Bad shapes, or an anchor id the result does not hold.
    """
    q = np.asarray(joints_deg, dtype=float)
    if q.ndim != 2 or q.shape[1] != N_JOINTS:
        raise ValueError(f"joints_deg: expected shape (n, 6), got {q.shape}")
    res = CalibrationResult.of(result)
    fit = res.anchor_fit(anchor)
    pos = forward_position(
        calibrated_dh_internal(res),
        result_table_rad(res, q),
        np.asarray(res.tool(), dtype=float),
        res.convention or "dh",
    )
    out: FloatArray = (
        np.linalg.norm(pos - np.asarray(fit.anchor_mm, dtype=float), axis=-1) + fit.length_offset_mm
    )
    return out
