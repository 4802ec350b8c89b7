"""What :func:`calib.planning.plan` returns, with its JSON summary and CSV rows."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from calib.csvtext import write_csv
from calib.kinematics import N_JOINTS, FloatArray, IndexArray
from calib.tcp import TcpUncertainty

#: Columns of the plan CSV, in order. ``q1..q6`` [deg] as ``identify`` reads them.
CSV_COLUMNS = (
    "pose",
    *(f"q{j + 1}" for j in range(N_JOINTS)),
    "anchor",
    "extension_mm",
    "anchor_x_mm",
    "anchor_y_mm",
    "anchor_z_mm",
)


def _finite(v: float) -> float | None:
    return float(v) if np.isfinite(v) else None


@dataclass(frozen=True)
class PlanResult:
    """A planned campaign and its predicted quality.

    Attributes
    ----------
    q_deg : ndarray, shape (n, 6)
        Planned poses in visiting order [deg].
    anchor_index : ndarray of int, shape (n,)
        Index into ``anchor_ids``/``anchors_mm`` of each pose.
    anchor_ids : tuple of str, length m
    anchors_mm : ndarray, shape (m, 3)
        Anchor positions the plan was made for (the user's guesses) [mm].
    extension_mm : ndarray, shape (n,)
        Predicted cable extension ``|p − P0|`` with the nominal model [mm].
    base : list of str
        Base (identifiable) parameters the design optimises, layout order.
    param_sigma : ndarray, shape (k,)
        Predicted 1σ of each base parameter (display units: deg or mm), start data included.
    param_units : list of str
    condition_number : float
        Of the unit-column Jacobian of the base set, planned poses plus start data.
    condition_number_start : float or None
        The same for the start data alone (None without start data).
    tcp : TcpUncertainty
        Predicted aligned TCP σ of the plan (with start data) over the workspace sample.
    tcp_random : dict
        ``{"rms": mean, "max": mean}`` [mm] of the same prediction for random poses drawn from
        the same feasible set, same count and anchors (averaged over several draws).
    offsets_mm : tuple of (float or None), optional
        The indicator's zero offset per anchor the plan kept the readings in range with [mm]
        (:attr:`calib.planning.PlanOptions.offsets_mm`); ``reading_window_mm`` the readings
        allowed [mm]. ``to_json``'s ``reading_mm``: the offsets, the window and the predicted
        readings' min and max (None without an offset).
    travel_s, campaign_s : float
        Estimated move time and campaign time (moves plus dwell) [s]; moving the sensor
        between anchors is not included.
    """

    q_deg: FloatArray
    anchor_index: IndexArray
    anchor_ids: tuple[str, ...]
    anchors_mm: FloatArray
    extension_mm: FloatArray
    base: list[str]
    param_sigma: FloatArray
    param_units: list[str]
    condition_number: float
    condition_number_start: float | None
    tcp: TcpUncertainty
    tcp_random: dict[str, float]
    travel_s: float
    campaign_s: float
    log_det: float
    exchanges: int
    n_candidates: int
    noise_mm: float
    anchor_gain: dict[str, Any] | None = None
    elapsed_s: float = 0.0
    notes: list[str] = field(default_factory=list)
    offsets_mm: tuple[float | None, ...] | None = None
    reading_window_mm: tuple[float, float] | None = None

    def readings_mm(self) -> FloatArray:
        """Predicted indicator reading of each pose (n,) [mm]: extension + the anchor's zero
        offset, NaN where the offset is not known."""
        offsets = np.array(
            [
                np.nan
                if self.offsets_mm is None or self.offsets_mm[k] is None
                else float(self.offsets_mm[k])
                for k in self.anchor_index
            ]
        )
        out: FloatArray = self.extension_mm + offsets
        return out

    def _readings_json(self) -> dict[str, Any] | None:
        if self.offsets_mm is None or all(c is None for c in self.offsets_mm):
            return None
        known = self.readings_mm()
        known = known[np.isfinite(known)]
        return {
            "offsets_mm": {aid: self.offsets_mm[k] for k, aid in enumerate(self.anchor_ids)},
            "window_mm": list(self.reading_window_mm) if self.reading_window_mm else None,
            "min": float(known.min()) if known.size else None,
            "max": float(known.max()) if known.size else None,
        }

    def csv_rows(self) -> list[dict[str, Any]]:
        """One mapping per planned pose, keys :data:`CSV_COLUMNS`."""
        rows = []
        for i, (q, k) in enumerate(zip(self.q_deg, self.anchor_index, strict=True)):
            a = self.anchors_mm[k]
            row: dict[str, Any] = {"pose": i + 1}
            row.update({f"q{j + 1}": round(float(q[j]), 4) for j in range(N_JOINTS)})
            row.update(
                {
                    "anchor": self.anchor_ids[k],
                    "extension_mm": round(float(self.extension_mm[i]), 1),
                    "anchor_x_mm": float(a[0]),
                    "anchor_y_mm": float(a[1]),
                    "anchor_z_mm": float(a[2]),
                }
            )
            rows.append(row)
        return rows

    def to_csv(self) -> str:
        """The plan as CSV text (header :data:`CSV_COLUMNS`)."""
        return write_csv(self.csv_rows(), CSV_COLUMNS)

    def to_json(self) -> dict[str, Any]:
        """JSON-able summary (no per-pose rows: see :meth:`csv_rows`)."""
        return {
            "n_poses": int(self.q_deg.shape[0]),
            "anchors": {
                aid: [float(v) for v in self.anchors_mm[k]] for k, aid in enumerate(self.anchor_ids)
            },
            "poses_per_anchor": {
                aid: int(np.count_nonzero(self.anchor_index == k))
                for k, aid in enumerate(self.anchor_ids)
            },
            "noise_mm": self.noise_mm,
            "condition_number": _finite(self.condition_number),
            "condition_number_start": (
                None
                if self.condition_number_start is None
                else _finite(self.condition_number_start)
            ),
            "parameters": [
                {"name": n, "sigma": float(s), "unit": u}
                for n, s, u in zip(self.base, self.param_sigma, self.param_units, strict=True)
            ],
            "tcp_sigma_mm": {"plan": self.tcp.to_dict(), "random": dict(self.tcp_random)},
            "travel_s": self.travel_s,
            "campaign_s": self.campaign_s,
            "log_det": self.log_det,
            "exchanges": self.exchanges,
            "n_candidates": self.n_candidates,
            "anchor_gain": self.anchor_gain,
            "elapsed_s": self.elapsed_s,
            "notes": list(self.notes),
            "reading_mm": self._readings_json(),
        }
