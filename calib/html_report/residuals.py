"""Per-sample residuals of a stored result, for the report's residual plots.

``result.json`` holds summary metrics only; the per-sample residuals need the samples. The
*after* residual uses the calibrated model exactly as stored
(:func:`calib.predict.predict_lengths_from_result`). The *before* model is the nominal DH
table (``dh − dh_error``, exact from the result) with the nominal tool point and every
anchor's P0 and offset fitted to the given samples, as :func:`calib.identify.identify` does
on its training rows. The nominal tool point is not in ``result.json``: it comes from the
caller's nominal model, else from the built-in model named by the result's ``robot``; when
neither exists the before residuals are left out (and the report says so).

Residual sign: measured minus model, ``L_meas − L_model`` [mm].
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.anchors import fit_anchors
from calib.cable import ParamLayout
from calib.dataset import SampleSet
from calib.kinematics import FloatArray
from calib.models import BUILTIN_MODELS, RobotModel, builtin_model
from calib.predict import predict_lengths_from_result
from calib.result import DH_KEYS, CalibrationResult, ResultLike


@dataclass(frozen=True)
class SampleResiduals:
    """Residuals per sample, measured minus model.

    Attributes
    ----------
    after_mm : ndarray, shape (n,)
        Against the calibrated model [mm].
    before_mm : ndarray, shape (n,) or None
        Against the nominal model with P0 and offset fitted to these samples [mm]; None when
        the nominal tool point is unknown.
    before_note : str
        How the before model was obtained, or why it is missing (shown in the report).
    """

    after_mm: FloatArray
    before_mm: FloatArray | None
    before_note: str


def _nominal_model(result: CalibrationResult, nominal: RobotModel | None) -> RobotModel | None:
    """The nominal model: the caller's, else the built-in one of the result's robot name."""
    if nominal is not None:
        return nominal
    name = result.robot
    if name is not None and name in BUILTIN_MODELS:
        return builtin_model(name)
    return None


def _nominal_dh_deg_mm(result: CalibrationResult) -> FloatArray:
    """``dh − dh_error`` from the result, shape (6, 4): alpha_deg, a_mm, d_mm, theta_deg."""
    if result.dh is None or result.dh_error is None:
        raise ValueError(f"dh/dh_error: expected six rows with {DH_KEYS}")
    cal = np.array([r.values() for r in result.dh], dtype=float).reshape(-1, 4)
    err = np.array([r.values() for r in result.dh_error], dtype=float).reshape(-1, 4)
    if cal.shape != (6, 4) or err.shape != (6, 4):
        raise ValueError(f"dh/dh_error: expected six joint rows, got {len(cal)} and {len(err)}")
    out: FloatArray = cal - err
    return out


def sample_residuals(
    result: ResultLike, samples: SampleSet, nominal: RobotModel | None = None
) -> SampleResiduals:
    """Before and after residuals of every sample.

    Parameters
    ----------
    result : CalibrationResult or mapping
        The result (a parsed ``result.json`` is loaded).
    samples : SampleSet
        ``n`` samples (joints (n, 6) [deg], lengths (n,) [mm]); every anchor id must be in
        the result.
    nominal : RobotModel, optional
        The nominal model the result was identified from (for its tool point); default the
        built-in model named by the result's ``robot``, if any.

    Raises
    ------
    ValueError
        A malformed result, or a sample anchor the result does not hold.
    """
    result = CalibrationResult.of(result)
    predicted = np.empty(len(samples))
    ids = np.asarray(samples.anchor)
    for aid in samples.anchor_ids:
        rows = ids == aid
        predicted[rows] = predict_lengths_from_result(result, samples.joints_deg[rows], aid)
    after = samples.length_mm - predicted
    per_sample = result.drift.per_sample_mm if result.drift else None
    if per_sample is not None and len(per_sample) == len(samples):
        after = after - np.asarray(per_sample, dtype=float)  # the drift is not the robot's

    model = _nominal_model(result, nominal)
    if model is None:
        return SampleResiduals(
            after,
            None,
            "No before residuals: the nominal tool point of "
            f"{result.robot!r} is unknown (not a built-in model)",
        )
    convention = result.convention or model.convention
    model = RobotModel(
        model.name,
        convention,
        _nominal_dh_deg_mm(result),
        model.joint_limits_deg,
        model.tool_mm,
        model.controller,
    )
    layout = ParamLayout(samples.anchor_ids)
    theta = fit_anchors(
        model,
        layout,
        np.zeros(layout.size),
        model.table_rad(samples.joints_deg),
        samples.anchor_index(),
        samples.length_mm,
    )
    before_result = {
        "dh": [
            {"alpha_deg": r[0], "a_mm": r[1], "d_mm": r[2], "theta_deg": r[3]}
            for r in model.dh_table.tolist()
        ],
        "convention": convention,
        "tool_mm": model.tool_mm.tolist(),
        "anchor_id": layout.anchors[0],
        "anchor_mm": theta[layout.anchor_slice(0)][:3].tolist(),
        "length_offset_mm": float(theta[layout.anchor_slice(0)][3]),
        "anchors": {
            aid: {
                "anchor_mm": theta[layout.anchor_slice(k)][:3].tolist(),
                "length_offset_mm": float(theta[layout.anchor_slice(k)][3]),
            }
            for k, aid in enumerate(layout.anchors)
            if k
        },
    }
    before_pred = np.empty(len(samples))
    for aid in samples.anchor_ids:
        rows = ids == aid
        before_pred[rows] = predict_lengths_from_result(
            before_result, samples.joints_deg[rows], aid
        )
    note = (
        "Before model: nominal DH table and tool point "
        f"({', '.join(f'{v:.1f}' for v in model.tool_mm)}) mm, P0 and offset fitted to "
        f"these {len(samples)} samples"
    )
    return SampleResiduals(after, samples.length_mm - before_pred, note)
