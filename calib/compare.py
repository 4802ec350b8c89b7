"""A new identification result next to the robot's current calibration (``GET
/identifications/{id}/compare``): what the operator reads before pressing Accept.

Both models are scored on the same rows, the new job's held-out rows (``split.
test_sample_ids`` of its ``result.json``; the ones still included in its campaign), so the
RMSE figures compare like with like. The parameters listed are the DH entries, the tool point
and the anchor that moved by more than :data:`CHANGE_TOL` (mm or deg).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from typing_extensions import TypedDict

from calib.dataset import SampleSet
from calib.result import CalibrationResult, ResultLike

#: Smallest change listed [mm or deg]: below the 0.001 the page and the CSVs round to.
CHANGE_TOL = 1e-3
_DH_KEYS = (("alpha_deg", "deg"), ("a_mm", "mm"), ("d_mm", "mm"), ("theta_deg", "deg"))


class ChangedParameter(TypedDict):
    """One parameter that differs between the two models, ``unit`` mm or deg."""

    name: str
    unit: str
    current: float
    new: float
    change: float


class ModelFigures(TypedDict):
    """One model's figures: ``job_id``, the method, the length RMSE [mm] on the compared rows
    (null without rows) and the predicted TCP 1σ RMS [mm] (null if not computed)."""

    job_id: int
    method: str | None
    test_rmse_mm: float | None
    tcp_sigma_mm: float | None


class Comparison(TypedDict):
    """``current`` is null when the robot has no calibration yet (then nothing changed)."""

    n_rows: int
    new: ModelFigures
    current: ModelFigures | None
    changed: list[ChangedParameter]


def _rmse(result: CalibrationResult, samples: SampleSet, rows: np.ndarray) -> float | None:
    from calib.predict import predict_lengths_from_result

    if rows.size == 0:
        return None
    errors = []
    for anchor in sorted({samples.anchor[i] for i in rows}):
        sel = rows[[samples.anchor[i] == anchor for i in rows]]
        try:
            pred = predict_lengths_from_result(result, samples.joints_deg[sel], anchor)
        except ValueError:
            return None  # the model does not know this anchor
        errors.append(pred - samples.length_mm[sel])
    err = np.concatenate(errors)
    value = float(np.sqrt(np.mean(err * err)))
    return value if math.isfinite(value) else None


def _figures(
    job_id: int, result: CalibrationResult, samples: SampleSet, rows: np.ndarray
) -> ModelFigures:
    sigma = (result.tcp_uncertainty_mm or {}).get("rms")
    return {
        "job_id": job_id,
        "method": result.method,
        "test_rmse_mm": _rmse(result, samples, rows),
        "tcp_sigma_mm": sigma,
    }


def _parameters(result: CalibrationResult) -> dict[str, tuple[float, str]]:
    out: dict[str, tuple[float, str]] = {}
    for row in result.dh or ():
        for (key, unit), value in zip(_DH_KEYS, row.values(), strict=True):
            out[f"{key.split('_')[0]}{row.joint}"] = (value, unit)
    for label, point in (("tool", result.tool_mm), ("anchor", result.anchor_mm)):
        for axis, value in zip("xyz", point or (), strict=False):
            out[f"{label}_{axis}"] = (value, "mm")
    if result.length_offset_mm is not None:
        out["length_offset"] = (result.length_offset_mm, "mm")
    return out


def compare_results(
    job_id: int,
    new: ResultLike,
    current_id: int | None,
    current: ResultLike | None,
    samples: SampleSet,
    sample_ids: Sequence[int],
) -> Comparison:
    """The :class:`Comparison` of result ``new`` (job ``job_id``) with ``current``.

    ``samples`` / ``sample_ids`` are the campaign's included samples; the rows compared are
    those whose id is in ``new``'s ``split.test_sample_ids``.
    """
    new = CalibrationResult.of(new)
    current = None if current is None else CalibrationResult.of(current)
    wanted = set((new.split.test_sample_ids if new.split else None) or ())
    rows = np.array([i for i, sid in enumerate(sample_ids) if sid in wanted], dtype=int)
    changed: list[ChangedParameter] = []
    if current is not None:
        before, after = _parameters(current), _parameters(new)
        for name, (value, unit) in after.items():
            if name in before and abs(value - before[name][0]) > CHANGE_TOL:
                changed.append(
                    {
                        "name": name,
                        "unit": unit,
                        "current": before[name][0],
                        "new": value,
                        "change": value - before[name][0],
                    }
                )
    return {
        "n_rows": int(rows.size),
        "new": _figures(job_id, new, samples, rows),
        "current": None
        if current is None or current_id is None
        else _figures(current_id, current, samples, rows),
        "changed": changed,
    }
