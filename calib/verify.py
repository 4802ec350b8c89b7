"""Verify a calibration on another campaign: predict its cable lengths from a stored result.

:func:`verify` predicts every sample's indicator reading with the calibrated model of a
``result.json`` mapping (:func:`calib.predict.predict_lengths_from_result`) and reports RMSE,
MAE, STD and MAX (:func:`calib.accuracy.length_metrics`) and the per-pose residuals
``measured − predicted``. A hold check compares the RMSE with ``max_rmse_mm``.

``refit_anchor=True`` is for a campaign taken after the sensor was moved or re-zeroed: the
robot's calibrated kinematics stay fixed and only each anchor's ``P0`` and zero offset ``c``
are fitted to the new data (:func:`calib.anchors.fit_anchors`: multilateration, then LM).
Four parameters per anchor absorb little, so a robot that drifted still shows.

:func:`aligned_rms_mm` is the RMS distance after the rigid (rotation + translation) alignment
of :func:`calib.tcp.aligned_position_error_mm`, used to compare positions whose base frame is
not observable from cable lengths.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from calib.accuracy import length_metrics
from calib.anchors import fit_anchors
from calib.cable import N_KIN, ParamLayout, predict_lengths
from calib.csvtext import write_csv
from calib.dataset import JOINT_COLUMNS, SampleSet
from calib.export import model_from_result
from calib.kinematics import FloatArray
from calib.predict import predict_lengths_from_result
from calib.result import CalibrationResult, ResultLike
from calib.tcp import aligned_position_error_mm


@dataclass(frozen=True)
class VerifyOptions:
    """Options of :func:`verify`.

    Attributes
    ----------
    refit_anchor : bool
        Fit each anchor's P0 and zero offset to the new data (sensor moved); the kinematics
        stay as calibrated.
    max_rmse_mm : float or None
        Tolerance of a hold check: ``passed`` is ``rmse_mm <= max_rmse_mm`` (None: no check).
    """

    refit_anchor: bool = False
    max_rmse_mm: float | None = None

    def __post_init__(self) -> None:
        if self.max_rmse_mm is not None and not (
            math.isfinite(self.max_rmse_mm) and self.max_rmse_mm > 0
        ):
            raise ValueError(f"max_rmse_mm must be a positive number, got {self.max_rmse_mm!r}")


@dataclass
class VerifyResult:
    """What :func:`verify` found.

    Attributes
    ----------
    metrics : dict
        ``n, rmse_mm, mae_mm, std_mm, max_mm`` over all samples.
    joints_deg : ndarray, shape (n, 6)
    measured_mm, predicted_mm, residual_mm : ndarray, shape (n,)
        ``residual = measured − predicted``.
    anchor : tuple of str, length n
    anchors : dict
        Per anchor id: ``anchor_mm``, ``length_offset_mm`` used, and ``refit``.
    reference_rmse_mm : float or None
        The identification's own RMSE after calibration (test rows, else train).
    passed : bool or None
        ``rmse_mm <= max_rmse_mm``; None without a tolerance.
    """

    metrics: dict[str, float]
    joints_deg: FloatArray
    measured_mm: FloatArray
    predicted_mm: FloatArray
    residual_mm: FloatArray
    anchor: tuple[str, ...]
    anchors: dict[str, dict[str, Any]]
    refit_anchor: bool
    reference_rmse_mm: float | None
    passed: bool | None
    notes: list[str] = field(default_factory=list)

    def csv_rows(self) -> list[dict[str, Any]]:
        """One mapping per sample: ``index, q1..q6, anchor, measured_mm, predicted_mm,
        residual_mm``."""
        rows = []
        for i in range(self.residual_mm.shape[0]):
            row: dict[str, Any] = {"index": i}
            row |= {c: float(v) for c, v in zip(JOINT_COLUMNS, self.joints_deg[i], strict=True)}
            row |= {
                "anchor": self.anchor[i],
                "measured_mm": float(self.measured_mm[i]),
                "predicted_mm": float(self.predicted_mm[i]),
                "residual_mm": float(self.residual_mm[i]),
            }
            rows.append(row)
        return rows

    def to_csv(self) -> str:
        """CSV text of :meth:`csv_rows`."""
        rows = self.csv_rows()
        return write_csv(rows, list(rows[0]))

    def to_json(self) -> dict[str, Any]:
        """``metrics, refit_anchor, anchors, reference_rmse_mm, passed, notes, residuals``."""
        return {
            "metrics": self.metrics,
            "refit_anchor": self.refit_anchor,
            "anchors": self.anchors,
            "reference_rmse_mm": self.reference_rmse_mm,
            "passed": self.passed,
            "notes": list(self.notes),
            "residuals": self.csv_rows(),
        }


def reference_rmse_mm(result: ResultLike) -> float | None:
    """The identification's own RMSE after calibration [mm]: test rows, else train."""
    res = CalibrationResult.of(result)
    for part in ("test", "train"):
        figures = res.figures("after", part)
        rmse = figures.get("rmse_mm")
        if figures.get("n") and rmse is not None:
            return float(rmse)
    return None


def _stored_anchors(result: CalibrationResult) -> dict[str, dict[str, Any]]:
    return {
        aid: {"anchor_mm": list(fit.anchor_mm), "length_offset_mm": fit.length_offset_mm}
        for aid, fit in result.anchor_fits().items()
    }


def verify(
    result: ResultLike, samples: SampleSet, options: VerifyOptions | None = None
) -> VerifyResult:
    """Predict another campaign's cable lengths from a result and report the errors.

    Parameters
    ----------
    result : CalibrationResult or mapping
        The calibration (a parsed ``result.json`` is loaded).
    samples : SampleSet
        The new campaign: joints (n, 6) [deg], lengths (n,) [mm], anchor ids.
    options : VerifyOptions

    Raises
    ------
    ValueError
        Without ``refit_anchor``: a sample's anchor id is not in the result (naming it).
        With it: an anchor with fewer than 5 samples.
    """
    opts = options or VerifyOptions()
    result = CalibrationResult.of(result)
    q = np.asarray(samples.joints_deg, dtype=float)
    aidx = samples.anchor_index()
    ids = samples.anchor_ids
    predicted = np.empty(len(samples))
    if opts.refit_anchor:
        model = model_from_result(result)
        layout = ParamLayout(ids)
        theta = fit_anchors(
            model, layout, np.zeros(layout.size), model.table_rad(q), aidx, samples.length_mm
        )
        predicted[:] = predict_lengths(model, theta, model.table_rad(q), aidx)
        fitted = theta[N_KIN:].reshape(-1, 4)
        anchors = {
            aid: {
                "anchor_mm": [float(v) for v in fitted[k, :3]],
                "length_offset_mm": float(fitted[k, 3]),
                "refit": True,
            }
            for k, aid in enumerate(ids)
        }
    else:
        stored = _stored_anchors(result)
        missing = [a for a in ids if a not in stored]
        if missing:
            raise ValueError(
                f"anchor: {missing} not in the result ({sorted(stored)}); "
                "use refit_anchor for a moved sensor"
            )
        for k, aid in enumerate(ids):
            rows = aidx == k
            predicted[rows] = predict_lengths_from_result(result, q[rows], aid)
        anchors = {aid: {**stored[aid], "refit": False} for aid in ids}
    figures = length_metrics(samples.length_mm, predicted)
    reference = reference_rmse_mm(result)
    passed = None if opts.max_rmse_mm is None else bool(figures["rmse_mm"] <= opts.max_rmse_mm)
    notes = []
    if reference is not None:
        notes.append(f"RMSE {figures['rmse_mm']:.4f} mm vs {reference:.4f} mm at identification")
    return VerifyResult(
        metrics=figures,
        joints_deg=q,
        measured_mm=np.asarray(samples.length_mm, dtype=float),
        predicted_mm=predicted,
        residual_mm=samples.length_mm - predicted,
        anchor=tuple(samples.anchor),
        anchors=anchors,
        refit_anchor=opts.refit_anchor,
        reference_rmse_mm=reference,
        passed=passed,
        notes=notes,
    )


def aligned_rms_mm(points_mm: FloatArray, reference_mm: FloatArray) -> float:
    """RMS distance [mm] after the best rigid alignment
    (:func:`calib.tcp.aligned_position_error_mm`); shapes (n, 3)."""
    res = aligned_position_error_mm(points_mm, reference_mm)
    return float(np.sqrt(np.mean(res * res)))
