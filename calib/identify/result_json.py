"""What an identification found, and the ``result.json`` it writes: :class:`IdentifyResult`
(:meth:`IdentifyResult.to_json` is the contract :class:`calib.result.CalibrationResult` reads),
and the blocks and notes it carries: the length figures, the robust step's note and block, the
measurement's drift block and its one wording (:func:`drift_summary`).

Units: internal values in millimetres and radians; every reported figure in degrees and
millimetres.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from calib.accuracy import length_metrics
from calib.cable import N_DH, N_KIN, ParamLayout
from calib.drift import DriftModel, Selection
from calib.identifiability import Identifiability
from calib.kinematics import N_JOINTS, FloatArray
from calib.models import RobotModel
from calib.options import SCREEN_MIN_DOF, IdentifyOptions, samples_for_training_rows
from calib.robust import GROSS_ERROR_MM, Solved
from calib.solvers.common import SolverResult


@dataclass
class IdentifyResult:
    """Everything :func:`calib.identify.identify` found; :meth:`to_json` gives the contract."""

    model: RobotModel
    layout: ParamLayout
    method: str
    theta: FloatArray  # (p,) identified full vector, internal units
    theta_before: FloatArray  # (p,) nominal kinematics, fitted anchors
    free_names: list[str]
    sigma: FloatArray  # (p,) 1σ in internal units, 0 for fixed parameters
    correlation: FloatArray  # (k, k) over free_names
    identifiability: Identifiability
    solver: SolverResult
    metrics: dict[str, dict[str, dict[str, float]]]
    flagged_rows: list[int]
    train_rows: np.ndarray
    test_rows: np.ndarray
    options: IdentifyOptions
    plausibility: dict[str, Any]
    notes: list[str] = field(default_factory=list)
    elapsed_s: float = 0.0
    #: (p,) where every method started: nominal DH, tool point and anchors fitted.
    theta_start: FloatArray | None = None
    #: Predicted 1σ tool-point error after best rigid alignment over a workspace sample,
    #: ``{"rms", "max"}`` [mm] (:func:`calib.tcp.tcp_uncertainty_for_problem`).
    tcp_uncertainty_mm: dict[str, float] | None = None
    #: ``result.json``'s ``prior`` block (:func:`calib.prior.prior_block`); None: from options.
    prior: dict[str, Any] | None = None
    #: The robust step: ``{"mode", "threshold", "fits"}`` (threshold in robust σ).
    robust_detail: dict[str, Any] | None = None
    #: ``result.json``'s ``drift`` block (:func:`drift_report`): how the measurement
    #: changed over the campaign, left out of every robot figure.
    drift: dict[str, Any] | None = None

    def dh_table_deg_mm(self, errors_only: bool = False) -> FloatArray:
        """Calibrated (or error) DH table, shape (6, 4): alpha_deg, a_mm, d_mm, theta_deg."""
        err = self.theta[:N_DH].reshape(N_JOINTS, 4).copy()
        err[:, [0, 3]] = np.rad2deg(err[:, [0, 3]])
        return err if errors_only else self.model.dh_table + err

    def tool_mm(self) -> FloatArray:
        return np.asarray(self._nominal_tool() + self.theta[N_DH:N_KIN], dtype=float)

    def _nominal_tool(self) -> FloatArray:
        return (
            np.asarray(self.options.tool_mm, dtype=float)
            if self.options.tool_mm is not None
            else self.model.tool_mm
        )

    def calibrated_model(self) -> RobotModel:
        """The calibrated robot as a model (same convention, joint limits kept)."""
        return replace(
            self.model,
            name=f"{self.model.name}-calibrated",
            dh_table=self.dh_table_deg_mm(),
            tool_mm=self.tool_mm(),
        )

    def to_json(self) -> dict[str, Any]:
        """The stable ``result.json`` contract (see README)."""

        def rows(table: FloatArray) -> list[dict[str, float | int]]:
            return [
                {
                    "joint": j + 1,
                    "alpha_deg": float(table[j, 0]),
                    "a_mm": float(table[j, 1]),
                    "d_mm": float(table[j, 2]),
                    "theta_deg": float(table[j, 3]),
                }
                for j in range(N_JOINTS)
            ]

        scale = self.layout.display_scale
        anchors: dict[str, dict[str, Any]] = {}
        for k, aid in enumerate(self.layout.anchors):
            vals = self.theta[self.layout.anchor_slice(k)]
            anchors[aid] = {
                "anchor_mm": [float(v) for v in vals[:3]],
                "length_offset_mm": float(vals[3]),
            }
        first = anchors[self.layout.anchors[0]]
        names = self.layout.names
        uncertainty = {
            names[i]: float(self.sigma[i] * scale[i]) for i in range(len(names)) if self.sigma[i]
        }
        return {
            "robot": self.model.name,
            "method": self.method,
            "convention": self.model.convention,
            "dh": rows(self.dh_table_deg_mm()),
            "dh_error": rows(self.dh_table_deg_mm(errors_only=True)),
            "tool_mm": [float(v) for v in self.tool_mm()],
            "anchor_mm": first["anchor_mm"],
            "length_offset_mm": first["length_offset_mm"],
            "anchor_id": self.layout.anchors[0],
            "anchors": {a: v for a, v in anchors.items() if a != self.layout.anchors[0]},
            "uncertainty": uncertainty,
            "tcp_uncertainty_mm": self.tcp_uncertainty_mm,
            "correlation": {
                "names": list(self.free_names),
                "matrix": [[round(float(v), 6) for v in row] for row in self.correlation],
            },
            "identifiability": self.identifiability.to_dict(),
            "metrics": self.metrics,
            "flagged_samples": list(self.flagged_rows),
            "iterations": int(self.solver.iterations),
            "elapsed_s": float(self.elapsed_s),
            "status": int(self.solver.status),
            "success": bool(self.solver.success),
            "message": self.solver.message,
            "cost_history_rms_mm": [float(v) for v in self.solver.cost_history_rms_mm],
            "cost_history_fit_starts": [int(i) for i in self.solver.fit_starts],
            "prior": self.prior
            or {
                "used": self.options.prior,
                "dh_mm": self.options.prior_mm,
                "dh_deg": self.options.prior_deg,
                "tool_mm": self.options.prior_tool_mm,
                "noise_mm": self.options.noise_mm,
            },
            "robust": self.options.robust,
            "robust_detail": self.robust_detail,
            "drift": self.drift,
            "split": {
                "holdout": self.options.holdout,
                "test_fraction": self.options.test_fraction,
                "seed": self.options.seed,
                "n_train": int(self.train_rows.size),
                "n_test": int(self.test_rows.size),
                "test_rows": [int(i) for i in self.test_rows],
            },
            "plausibility": self.plausibility,
            "notes": list(self.notes),
            **self.model.controller_fields(),
        }


def length_figures(
    measured_mm: FloatArray,
    rows_by_part: dict[str, np.ndarray],
    predicted: dict[str, Callable[[np.ndarray], FloatArray]],
) -> dict[str, dict[str, dict[str, float]]]:
    """Length metrics (:func:`calib.accuracy.length_metrics`) per model label (``before``,
    ``after``) and per part (``train``, ``test``): ``measured_mm`` (n,) [mm] of every sample,
    ``rows_by_part`` the rows of each part, ``predicted[label](rows)`` the lengths (r,) [mm]
    that model predicts at ``rows`` (the after model's with the drift terms at their times)."""
    out: dict[str, dict[str, dict[str, float]]] = {}
    for label, predict in predicted.items():
        out[label] = {}
        for part, rows in rows_by_part.items():
            out[label][part] = length_metrics(measured_mm[rows], predict(rows))
    return out


def robust_note(opts: IdentifyOptions, s: Solved, n_train: int, n_samples: int) -> str:
    """The note on what the robust step did, from ``n_train`` training rows of ``n_samples``."""
    scr = s.screening
    if opts.robust == "auto" and scr is not None and not scr.screening:
        train = n_train + scr.rows_short()
        more = max(
            samples_for_training_rows(train, opts.test_fraction) - n_samples, scr.rows_short()
        )
        gross = (
            f"{s.flagged.size} gross error(s) beyond {GROSS_ERROR_MM:g} mm rejected "
            "and refit from the start; "
            if s.flagged.size
            else ""
        )
        return (
            f"robust auto: {gross}too few samples to screen outliers: {more} more would "
            f"allow it (redundancy {scr.redundancy:.1f}, screening needs "
            f"{SCREEN_MIN_DOF}); only a residual beyond "
            f"{GROSS_ERROR_MM:g} mm is rejected"
        )
    if opts.robust == "auto" and s.flagged.size == 0:
        return (
            f"robust auto: no gross outlier (largest residual {float(s.u.max()):.1f} "
            f"robust σ, threshold {s.threshold:.2f}): the plain fit"
        )
    how = {
        "auto": "rejected, refit from the start",
        "reject": "rejected, refit from the start",
        "huber": "down-weighted",
        "soft_l1": "down-weighted",
    }[opts.robust]
    return (
        f"robust {opts.robust}: {s.flagged.size} flagged beyond {s.threshold:.2f} robust σ "
        f"({how}; {s.fits} fit(s))"
    )


def robust_detail(opts: IdentifyOptions, s: Solved) -> dict[str, Any]:
    """``result.json``'s ``robust_detail``: the threshold [robust σ] (null when not screening),
    the fits, and whether the residuals were screened at what redundancy."""
    scr = s.screening
    return {
        "mode": opts.robust,
        "threshold": s.threshold if np.isfinite(s.threshold) else None,
        "fits": s.fits,
        "screened": None if scr is None else scr.screening,
        "redundancy": None if scr is None else scr.redundancy,
    }


def drift_report(
    model: DriftModel, beta: FloatArray, selection: Selection | None, mode: str
) -> dict[str, Any]:
    """``result.json``'s ``drift`` block: the model, the steps (row, kind, sizes [mm]), the
    smooth drift (knots, values [mm], peak-to-peak [mm], steepest rate [mm/h or mm per 100
    samples]) and the criterion's scores (BIC, leave-one-out PRESS [mm²]), and the gross
    outliers left out of the choice. The caller adds
    ``per_sample_mm`` (n,): the drift term at every sample [mm], in sample order, and
    ``rows_flagged``: the rows (0-based) the robust screen left out of the fit."""
    per = "mm_per_h" if model.time_unit == "s" else "mm_per_100_samples"
    scale = 3600.0 if model.time_unit == "s" else 100.0
    out: dict[str, Any] = {
        "mode": mode,
        "model": model.name,
        "time_unit": model.time_unit,
        "n_columns": model.n_columns,
        "steps": [],
        "smooth": None,
    }
    n_smooth = max(len(model.knots) - 1, 0)
    smooth_beta = beta[:n_smooth]
    j = n_smooth
    for s in model.steps:
        entry: dict[str, Any] = {
            "row": s.row,
            "t": s.t,
            "kind": s.kind,
            "offset_mm": float(beta[j]),
        }
        if s.kind == "sensor_moved":
            delta = beta[j + 1 : j + 4]
            entry["p0_shift_mm"] = [float(v) for v in delta]
            entry["size_mm"] = float(np.linalg.norm(delta))
            j += 4
        else:
            entry["size_mm"] = abs(float(beta[j]))
            j += 1
        out["steps"].append(entry)
    if model.knots:
        knots = np.asarray(model.knots)
        values = np.concatenate([[0.0], smooth_beta])
        slopes = np.diff(values) / np.maximum(np.diff(knots), 1e-12) * scale
        out["smooth"] = {
            "knots_t": [float(v) for v in knots],
            "values_mm": [float(v) for v in values],
            "peak_to_peak_mm": float(np.ptp(values)),
            f"max_rate_{per}": float(np.max(np.abs(slopes))) if slopes.size else 0.0,
            f"mean_rate_{per}": float(
                (values[-1] - values[0]) / max(knots[-1] - knots[0], 1e-12) * scale
            ),
        }
    if selection is not None:
        out["bic"] = {k: round(v, 3) for k, v in selection.bic.items()}
        out["loo_press_mm2"] = {k: round(v, 6) for k, v in selection.press_mm2.items()}
        out["rows_left_out_of_the_choice"] = selection.excluded_rows
    return out


def drift_summary(block: Mapping[str, Any]) -> str:
    """The one wording of what :func:`drift_report`'s ``block`` found: the result carries it
    (``drift.summary``) and the CLI, the operator page and the HTML report read it. A block
    with a ``note`` (a method that does not model drift) says it was not looked for, never
    that the measurement held still.

    Samples set aside (``rows_left_out_of_the_choice``: gross outliers of the drift choice;
    ``rows_flagged``: the robust screen's outliers) are named: a step among them is not seen,
    so "held still" is said only when every sample was kept."""
    if block.get("note"):
        return (
            f"drift {block['mode']}: {block['note']}, so steps and drift of the "
            "measurement were not looked for"
        )
    aside = sorted({*block.get("rows_left_out_of_the_choice", ()), *block.get("rows_flagged", ())})
    left = ""
    if aside:
        shown = ", ".join(str(r) for r in aside[:8]) + (", …" if len(aside) > 8 else "")
        left = (
            f"{len(aside)} sample(s) left out as outliers (rows {shown}): a step or drift "
            "among them is not seen; check them"
        )
    if block["model"] == "none":
        if left:
            return f"drift {block['mode']}: none found among the samples kept; {left}"
        return f"drift {block['mode']}: none found (the measurement held still)"
    per = "mm/h" if block["time_unit"] == "s" else "mm/100 samples"
    parts = []
    for s in block["steps"]:
        what = "sensor moved" if s["kind"] == "sensor_moved" else "indicator re-zeroed"
        parts.append(f"{what} at row {s['row']} ({s['size_mm']:.2f} mm)")
    sm = block["smooth"]
    if sm is not None:
        key = next(k for k in sm if k.startswith("max_rate_"))
        parts.append(
            f"smooth offset drift over {len(sm['knots_t'])} knots, "
            f"{sm['peak_to_peak_mm']:.2f} mm peak to peak, up to {sm[key]:.2f} {per}"
        )
    found = "; ".join(parts) + " (left out of the robot's figures)"
    return f"drift {block['mode']}: {found}" + (f"; {left}" if left else "")
