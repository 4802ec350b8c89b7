"""Hold checks, pure: does a calibrated robot still hold its accepted calibration?

The daemon's hold check (:mod:`daemon.monitors.holdcheck`; its settings, route, events and metrics
are named ``hold_check`` too) makes the robot revisit a few check poses and compares
the captures with the calibration's predictions. This module decides, from numbers only:

- :func:`spread_indices`: the default check poses, well spread among the calibration's own;
- :func:`covered`: which check poses a capture has reached;
- :func:`threshold_mm` and :func:`judge`: the RMS above which a check is ``not_held``;
- :func:`evaluate`: the comparison (:func:`calib.verify.verify`, without refitting the
  anchor by default) and, with :func:`change_jacobians`, whether a moved sensor or a robot
  change explains the residuals better (:func:`calib.monitor.stepwatch.explain_change`,
  worded by :func:`explanation_text`).

Not to be confused with :mod:`calib.drift`, the measurement drifting within one campaign.
``calib.verify`` and ``calib.predict`` are imported inside the functions that use them.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal, get_args

import numpy as np

from calib.kinematics import FloatArray
from calib.monitor.stepwatch import explain_change
from calib.result import CalibrationResult, ResultLike

#: What a finished check concludes; the store's check states
#: (:data:`daemon.store.rows.CheckStatus`) add ``running`` and ``failed`` to these.
CheckVerdict = Literal["ok", "not_held"]
CHECK_VERDICTS: tuple[str, ...] = get_args(CheckVerdict)


def threshold_mm(
    reference_rmse_mm: float | None,
    absolute_mm: float | None,
    factor: float,
    min_threshold_mm: float,
) -> float:
    """The RMS [mm] above which a check is ``not_held``.

    ``absolute_mm`` when set (the setting ``hold_check.threshold_mm``); else ``factor ×
    reference_rmse_mm`` (the calibration's own residual RMSE; ``hold_check.threshold_factor``), at
    least ``min_threshold_mm`` (``hold_check.min_threshold_mm``).

    Raises
    ------
    ValueError
        No absolute threshold and no usable reference RMSE.
    """
    if absolute_mm is not None:
        return float(absolute_mm)
    if reference_rmse_mm is None or not math.isfinite(reference_rmse_mm):
        raise ValueError("hold_check.threshold_mm: the calibration has no residual RMSE; set one")
    return max(factor * float(reference_rmse_mm), min_threshold_mm)


def judge(rms_mm: float, limit_mm: float) -> CheckVerdict:
    """``not_held`` when ``rms_mm`` exceeds ``limit_mm`` (equal is ok); a NaN RMS is
    ``not_held``."""
    return "ok" if rms_mm <= limit_mm else "not_held"


def spread_indices(joints_deg: FloatArray, k: int) -> list[int]:
    """``k`` well-spread rows of ``joints_deg`` (shape (n, 6) [deg]), in row order.

    Farthest-point sampling on the max-abs joint distance, starting from the pose nearest to
    the mean pose: deterministic, and every pose far from the chosen ones. ``k >= n`` gives
    all rows.
    """
    q = np.asarray(joints_deg, dtype=float)
    n = q.shape[0]
    if k >= n:
        return list(range(n))
    first = int(np.argmin(np.abs(q - q.mean(axis=0)).max(axis=1)))
    chosen = [first]
    dist = np.abs(q - q[first]).max(axis=1)
    while len(chosen) < k:
        nxt = int(np.argmax(dist))
        chosen.append(nxt)
        dist = np.minimum(dist, np.abs(q - q[nxt]).max(axis=1))
    return sorted(chosen)


def covered(
    poses_deg: FloatArray | Sequence[Sequence[float]],
    captured_deg: FloatArray | Sequence[Sequence[float]],
    tol_deg: float,
) -> FloatArray:
    """Per check pose (rows of ``poses_deg``, (m, 6)), whether a capture (rows of
    ``captured_deg``, (n, 6)) lies within ``tol_deg`` on every joint: bool array (m,)."""
    p = np.asarray(poses_deg, dtype=float)
    c = np.asarray(captured_deg, dtype=float).reshape(-1, 6)
    if c.shape[0] == 0:
        return np.zeros(p.shape[0], dtype=bool)
    near: FloatArray = (np.abs(p[:, None, :] - c[None, :, :]).max(axis=2) <= tol_deg).any(axis=1)
    return near


@dataclass
class Evaluation:
    """What :func:`evaluate` found: ``status`` ok/drift, the figures, the threshold."""

    status: CheckVerdict
    metrics: dict[str, float]
    threshold_mm: float
    detail: dict[str, Any]


def change_jacobians(
    result: ResultLike, joints_deg: FloatArray, anchors: tuple[str, ...]
) -> tuple[FloatArray, FloatArray]:
    """At the check poses ``joints_deg`` (n, 6) [deg] with their anchor ids: the length's
    derivatives by the anchor's P0 and offset, ``(−u, 1)`` (n, 4) [mm/mm], and by each
    joint's zero offset (n, 6) [mm/deg] (central differences of the result's predictions)."""
    from calib.kinematics import forward_position
    from calib.predict import calibrated_dh_internal, predict_lengths_from_result, result_table_rad

    res = CalibrationResult.of(result)
    q = np.asarray(joints_deg, dtype=float)
    pos = forward_position(
        calibrated_dh_internal(res),
        result_table_rad(res, q),
        np.asarray(res.tool(), dtype=float),
        res.convention or "dh",
    )
    p0 = np.array([res.anchor_fit(a).anchor_mm for a in anchors], dtype=float)
    diff = pos - p0
    unit = diff / np.linalg.norm(diff, axis=1)[:, None]
    anchor_jac = np.hstack([-unit, np.ones((q.shape[0], 1))])
    step_deg = 1e-3
    joint_jac = np.zeros((q.shape[0], 6))
    for j in range(6):
        lengths = []
        for sign in (1.0, -1.0):
            shifted = res.with_theta_shift(j, sign * step_deg)
            lengths.append(
                np.concatenate(
                    [
                        predict_lengths_from_result(shifted, q[i : i + 1], anchors[i])
                        for i in range(q.shape[0])
                    ]
                )
            )
        joint_jac[:, j] = (lengths[0] - lengths[1]) / (2 * step_deg)
    return anchor_jac, joint_jac


def explanation_text(explained: dict[str, Any]) -> str:
    """What moved, in the operator's words with its figure and the next step, from the
    explanation of :func:`calib.monitor.stepwatch.explain_change`: a moved sensor stand is
    the sensor's (check the stand), a joint's zero offset the robot's (calibrate again)."""
    if explained["kind"] == "sensor":
        shift = [float(v) for v in explained["anchor_shift_mm"]]
        size = math.sqrt(sum(v * v for v in shift))
        parts = ", ".join(f"{v:+.1f}" for v in shift)
        return (
            f"the sensor stand moved by {size:.1f} mm (P0 shift [{parts}] mm, offset "
            f"{explained['offset_change_mm']:+.2f} mm), not the robot; check the stand and "
            "its mounting, then check again (the robot's calibration still holds)"
        )
    if explained["kind"] == "robot":
        return (
            f"the robot changed: joint {explained['joint']} zero offset "
            f"{explained['joint_offset_deg']:+.3f} deg; calibrate the robot again"
        )
    return (
        "robot or sensor: the check poses cannot tell which moved; check the sensor stand, "
        "then calibrate the robot again if the next check fails to hold too"
    )


def evaluate(result: ResultLike, samples: Any, limit_mm: float, refit_anchor: bool) -> Evaluation:
    """Compare a check campaign's samples (a :class:`calib.dataset.SampleSet`) with a
    ``result.json`` mapping's predictions (:func:`calib.verify.verify`) and judge them.

    Without ``refit_anchor``, ``detail["explanation"]`` says whether a moved sensor (a P0
    shift and an offset change) or a robot change (one joint's zero offset) explains the
    residuals better (:func:`calib.monitor.stepwatch.explain_change`)."""
    from calib.planning.options import PLAN_NOISE_MM
    from calib.verify import VerifyOptions, verify

    result = CalibrationResult.of(result)
    out = verify(result, samples, VerifyOptions(refit_anchor=refit_anchor, max_rmse_mm=limit_mm))
    figures = {k: float(v) for k, v in out.metrics.items()}
    detail: dict[str, Any] = {
        "reference_rmse_mm": out.reference_rmse_mm,
        "anchors": out.anchors,
        "residual_mm": [float(v) for v in out.residual_mm],
    }
    if not refit_anchor:
        anchor_jac, joint_jac = change_jacobians(result, out.joints_deg, out.anchor)
        # Without the calibration's residual RMSE, the noise floor is the planner's assumed
        # noise of one captured length.
        noise = out.reference_rmse_mm or PLAN_NOISE_MM
        detail["explanation"] = explain_change(out.residual_mm, anchor_jac, joint_jac, noise)
    return Evaluation(judge(figures["rmse_mm"], limit_mm), figures, limit_mm, detail)
