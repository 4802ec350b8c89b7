"""Predict cable lengths from a stored ``result.json`` (the contract of
:meth:`calib.identify.IdentifyResult.to_json`), e.g. to check a calibrated model against
new poses or against an emulated cell's truth."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from calib.conventions import convention_from_mapping
from calib.kinematics import N_JOINTS, FloatArray, forward_position


def result_table_rad(result: Mapping[str, Any], joints_deg: FloatArray) -> FloatArray:
    """Table angles [rad] of controller joint angles [deg] (shape kept) under the result's
    ``controller`` block (identity when absent; :mod:`calib.conventions`)."""
    convention = convention_from_mapping(result.get("controller"))
    out: FloatArray = np.deg2rad(convention.to_table_deg(joints_deg))
    return out


def calibrated_dh_internal(result: Mapping[str, Any]) -> FloatArray:
    """The calibrated DH table of a result, shape (6, 4): ``(alpha_rad, a_mm, d_mm, theta_rad)``.

    Raises
    ------
    ValueError
        ``dh`` is missing or has not six joints.
    """
    rows = result.get("dh")
    if not isinstance(rows, list) or len(rows) != N_JOINTS:
        raise ValueError("dh: expected a list of six joint rows")
    table = np.array(
        [[r["alpha_deg"], r["a_mm"], r["d_mm"], r["theta_deg"]] for r in rows], dtype=float
    )
    table[:, [0, 3]] = np.deg2rad(table[:, [0, 3]])
    return table


def predict_lengths_from_result(
    result: Mapping[str, Any],
    joints_deg: FloatArray | Sequence[Sequence[float]],
    anchor: str | None = None,
) -> FloatArray:
    """Cable lengths the calibrated model predicts: ``L = |p_tcp(q) - P0| + c``.

    Parameters
    ----------
    result : mapping
        A ``result.json`` mapping (``dh``, ``convention``, ``tool_mm``, ``anchor_mm``,
        ``length_offset_mm``, ``anchor_id``, ``anchors``).
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
    first = result.get("anchor_id", "A")
    if anchor is None or anchor == first:
        p0, c = result["anchor_mm"], result["length_offset_mm"]
    else:
        others = result.get("anchors") or {}
        if anchor not in others:
            raise ValueError(f"anchor: {anchor!r} is not in the result ({[first, *others]})")
        p0, c = others[anchor]["anchor_mm"], others[anchor]["length_offset_mm"]
    pos = forward_position(
        calibrated_dh_internal(result),
        result_table_rad(result, q),
        np.asarray(result["tool_mm"], dtype=float),
        result.get("convention", "dh"),
    )
    out: FloatArray = np.linalg.norm(pos - np.asarray(p0, dtype=float), axis=-1) + float(c)
    return out
