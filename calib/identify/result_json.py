"""What an identification reports: the result type and its ``result.json``, the covariance of the
estimate, and the plausibility of every identified parameter against physical bounds.

Units: internal values in millimetres and radians; every reported figure in degrees and
millimetres.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from calib.accuracy import length_metrics
from calib.cable import N_DH, N_KIN, ParamLayout, length_jacobian
from calib.drift import DriftModel, Selection
from calib.identifiability import Identifiability
from calib.kinematics import N_JOINTS, FloatArray
from calib.models import RobotModel
from calib.options import SCREEN_MIN_DOF, IdentifyOptions, samples_for_training_rows
from calib.problem import Problem
from calib.robust import GROSS_ERROR_MM, Solved
from calib.solvers.common import SolverResult

#: Plausible magnitudes, in display units, used by the plausibility report.
PLAUSIBLE_DH_MM = 10.0
PLAUSIBLE_DH_DEG = 1.0
PLAUSIBLE_TOOL_MM = 500.0
PLAUSIBLE_ANCHOR_MM = 5000.0
PLAUSIBLE_OFFSET_MM = 2000.0
CABLE_EXTENSION_MAX_MM = 2050.0


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


def covariance(problem: Problem, x: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Free-parameter covariance (k, k) in internal units and σ̂ [mm]."""
    pred, jac_full = length_jacobian(
        problem.model, problem.full(x), problem.q_rad, problem.anchor_index
    )
    sw = np.sqrt(problem.weights)
    res = problem.project(sw * (pred - problem.length_mm))  # drift terms profiled out
    jac = problem.project(sw[:, None] * jac_full[:, problem.free])
    k = jac.shape[1]
    dof = max(int(np.count_nonzero(problem.weights > 0)) - k - problem.n_drift, 1)
    sigma2 = max(float(res @ res) / dof, 1e-18)
    d = np.linalg.norm(jac, axis=0)
    d = np.where(d > 0, d, 1.0)
    info = (jac / d).T @ (jac / d) / sigma2
    if problem.has_prior:
        assert problem.prior_sigma is not None
        ps = problem.prior_sigma[problem.free]
        info = info + np.diag(np.where(np.isfinite(ps), 1.0 / (ps * ps), 0.0) / (d * d))
    evals, evecs = np.linalg.eigh(info)
    cutoff = evals.max() * 1e-15
    inv = np.where(evals > cutoff, 1.0 / np.where(evals > cutoff, evals, 1.0), 0.0)
    cov_scaled = (evecs * inv) @ evecs.T
    return cov_scaled / np.outer(d, d), np.array(np.sqrt(sigma2))


def uncertainty(
    problem: Problem, x: FloatArray, cov: FloatArray | None = None
) -> tuple[FloatArray, FloatArray]:
    """1σ per parameter, shape (p,) in internal units (0 for fixed ones), and the correlation
    matrix of the free parameters, shape (k, k), at ``x`` (shape (k,)); ``cov`` is
    :func:`covariance` at ``x`` when the caller has it already."""
    if cov is None:
        cov, _ = covariance(problem, x)
    sig_free = np.sqrt(np.clip(np.diag(cov), 0, None))
    sigma = np.zeros(problem.layout.size)
    sigma[problem.free] = sig_free
    denom = np.outer(sig_free, sig_free)
    corr = np.divide(cov, denom, out=np.zeros_like(cov), where=denom > 0)
    return sigma, corr


def plausible_bounds(layout: ParamLayout) -> FloatArray:
    """Plausible magnitude of every parameter, shape (p,), in display units (deg, mm): of the
    error for DH parameters, of the absolute value for the others."""
    out = np.full(layout.size, PLAUSIBLE_ANCHOR_MM)
    for i, name in enumerate(layout.names):
        if i < N_DH:
            out[i] = PLAUSIBLE_DH_DEG if layout.is_angle[i] else PLAUSIBLE_DH_MM
        elif i < N_KIN:
            out[i] = PLAUSIBLE_TOOL_MM
        elif name.startswith("offset"):
            out[i] = PLAUSIBLE_OFFSET_MM
    return out


def plausibility(
    layout: ParamLayout, theta: FloatArray, nominal_tool: FloatArray, extension_mm: FloatArray
) -> dict[str, Any]:
    """Every parameter against its plausible bound, and the cable extension (mm) against the
    sensor's range: ``plausible``, ``outside_bounds``, ``cable_extension_mm``, ``parameters``.

    ``theta`` shape (p,) internal units; ``nominal_tool`` (3,) [mm]; ``extension_mm`` (n,).
    """
    scale = layout.display_scale
    names = layout.names
    bounds = plausible_bounds(layout)
    items = []
    for i, name in enumerate(names):
        value = float(theta[i] * scale[i])
        bound, kind = float(bounds[i]), "error" if i < N_DH else "absolute"
        if N_DH <= i < N_KIN:
            value = float(nominal_tool[i - N_DH] + theta[i])
        items.append(
            {
                "name": name,
                "value": value,
                "unit": layout.units[i],
                "kind": kind,
                "bound": bound,
                "ok": bool(abs(value) <= bound),
            }
        )
    ext_ok = bool(
        extension_mm.size == 0
        or (extension_mm.min() > 0 and extension_mm.max() <= CABLE_EXTENSION_MAX_MM)
    )
    outside = [it["name"] for it in items if not it["ok"]]
    return {
        "plausible": not outside and ext_ok,
        "outside_bounds": outside,
        "cable_extension_mm": {
            "min": float(extension_mm.min()) if extension_mm.size else None,
            "max": float(extension_mm.max()) if extension_mm.size else None,
            "ok": ext_ok,
        },
        "parameters": items,
    }


#: How many parameters the advice names, and how many terms of the weakest direction.
ADVICE_NAMES = 4


def weakest_direction(
    layout: ParamLayout, free_names: list[str], cov: FloatArray
) -> list[tuple[str, float]]:
    """The least constrained combination of the solved parameters, relative to their plausible
    sizes: the top eigenvector of ``D⁻¹ C D⁻¹`` (``C`` the (k, k) covariance in internal units,
    ``D`` the plausible bounds in internal units), as ``(name, coefficient)`` pairs, largest
    first (at most :data:`ADVICE_NAMES`), the sign fixed so the first is positive."""
    idx = [layout.index(n) for n in free_names]
    if not idx:
        return []
    bound = plausible_bounds(layout)[idx] / layout.display_scale[idx]
    scaled = cov / np.outer(bound, bound)
    _, vecs = np.linalg.eigh(scaled)
    v = vecs[:, -1]
    order = np.argsort(-np.abs(v))[:ADVICE_NAMES]
    sign = 1.0 if v[order[0]] >= 0 else -1.0
    return [(free_names[i], round(float(sign * v[i]), 2)) for i in order if abs(v[i]) >= 0.1]


def implausibility_advice(
    layout: ParamLayout,
    free_names: list[str],
    sigma: FloatArray,
    cov: FloatArray,
    plaus: dict[str, Any],
    options: IdentifyOptions,
) -> str:
    """The note of an implausible result: what is out of bounds, which parameters the data
    leave least constrained (largest 1σ against the plausible bound, and the weakest
    direction), and what to do: plan poses that excite them (``cablecal plan --start``), and
    ``--prior`` only when it is off. ``sigma`` (p,) 1σ in internal units; ``cov`` (k, k)."""
    scale, bounds = layout.display_scale, plausible_bounds(layout)
    idx = [layout.index(n) for n in free_names]
    ratio = sigma[idx] * scale[idx] / bounds[idx]
    loose = [idx[i] for i in np.argsort(-ratio)[:ADVICE_NAMES]]
    loose_text = ", ".join(
        f"{layout.names[i]} ±{sigma[i] * scale[i]:.3g} {layout.units[i]}" for i in loose
    )
    direction = " ".join(f"{c:+.2f}·{n}" for n, c in weakest_direction(layout, free_names, cov))
    outside = ", ".join(plaus["outside_bounds"][:6]) or "no parameter"
    if not plaus["cable_extension_mm"]["ok"]:
        outside += ", cable extension"
    text = (
        f"identified parameters are physically implausible ({outside}): the data do not "
        f"hold them within bounds. Least constrained (1σ): {loose_text}; "
        f"weakest direction: {direction}. "
        "Measure poses that excite these: `cablecal plan --start DATA.csv` plans the next "
        "poses given those already measured"
    )
    if options.prior:
        return text + (
            f" (the prior, {options.prior_mm} mm / {options.prior_deg} deg, is on and does not "
            "hold them at this weight)"
        )
    return text + "; or constrain them toward the nominal model with --prior"


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
