"""Options of :func:`calib.planning.plan`. Standard library only, so the CLI's ``--help``
reads the defaults from here without loading numpy."""

from __future__ import annotations

import math
from dataclasses import dataclass

#: Default joint speeds for a campaign's moves [deg/s]: a cautious fraction of a 6-axis
#: industrial robot's maximum axis speeds (base axes slower than wrist axes).
DEFAULT_JOINT_SPEED_DEG_S = (30.0, 30.0, 30.0, 45.0, 45.0, 60.0)

#: The 1σ noise of one captured length a plan assumes when it is given none [mm]. A capture
#: is the mean of a settled window of readings, so its noise is below one reading's; the
#: figure is a chosen round value, not a measurement. It scales the predicted σ only: the
#: information matrix is divided by its square, so which poses are chosen does not depend on
#: it. The daemon replaces it by the cell's own figure when it has one
#: (:mod:`daemon.api.plan_noise`); the hold check's step test also falls back to it
#: (:func:`calib.monitor.holdcheck.evaluate`).
PLAN_NOISE_MM = 0.05


@dataclass(frozen=True)
class PlanOptions:
    """Options of :func:`plan`; units in the names.

    Attributes
    ----------
    n : int
        Poses to plan (in total over all anchors).
    anchor_ids : tuple of str, optional
        Ids of the anchors (default ``A, B, …``); an id equal to one in the start data means
        the sensor has not moved (shared P0 and offset).
    candidates : int
        Random feasible candidate poses (in total over all anchors).
    seed : int
        Seeds candidates, anchor hypotheses, random baseline and workspace sample.
    min_z_mm : float
        Flange origin and tool point must stay above this height in the base frame [mm].
    extension_mm : (float, float)
        Allowed cable extension ``|p − P0|`` [mm] (HY150-2000: 2000 mm stroke).
    anchor_uncertainty_mm : float
        How far the anchor guess may be off [mm]: the stroke is shrunk by it and the
        criterion is summed over ``anchor_draws`` anchors this far from the guess.
    offsets_mm : tuple of (float or None), optional
        The indicator's zero offset ``c`` per anchor (the reading is ``|p − P0| + c``) [mm],
        e.g. from the accepted calibration or the campaign's running fit: each planned pose's
        predicted reading then stays within the indicator's range
        (:func:`calib.planning.candidates.reading_window_mm`). None, or None for an anchor:
        not known, only the cable extension is bounded.
    noise_mm : float
        1σ length noise for the predicted parameter and TCP σ [mm] (:data:`PLAN_NOISE_MM`).
    joint_speed_deg_s : 6 floats
        Joint speeds for the campaign's moves [deg/s].
    dwell_s : float
        Time per pose for settling and reading [s].
    anchors_nuisance : bool
        True (default): Ds-optimal, the anchors' P0 and offset are nuisance parameters and
        the criterion is the information about the kinematic base parameters once they are
        eliminated; this is what lets several anchors be compared fairly. False: plain
        D-optimal on the whole base set.
    max_exchanges : int
        Cap on Fedorov exchanges (each takes the best of all design × candidate swaps).
    workspace_poses : int
        Size of the workspace sample for the predicted TCP σ (above ``min_z_mm``).
    random_draws : int
        Random designs averaged for the side-by-side TCP σ.
    ridge : float
        Information added to every scaled parameter so the first greedy picks are defined.
    rtol : float
        Rank tolerance of the base-set analysis (:func:`calib.identifiability.analyse`).
    compare_single_anchors : bool
        With several anchors, also plan at each anchor alone and report the gain.
    criterion : str
        ``"tcp"`` (default): the D/Ds-optimal design is then refined by exchanges that lower
        the predicted mean aligned TCP variance over the workspace sample (I-optimality,
        summed over the anchor hypotheses), the figure a calibration is judged by.
        ``"d"``: stop at the D/Ds-optimal design.
    """

    n: int = 40
    anchor_ids: tuple[str, ...] | None = None
    candidates: int = 3000
    seed: int = 0
    min_z_mm: float = 0.0
    extension_mm: tuple[float, float] = (50.0, 1950.0)
    anchor_uncertainty_mm: float = 30.0
    anchor_draws: int = 2
    offsets_mm: tuple[float | None, ...] | None = None
    noise_mm: float = PLAN_NOISE_MM
    joint_speed_deg_s: tuple[float, ...] = DEFAULT_JOINT_SPEED_DEG_S
    dwell_s: float = 3.0
    max_exchanges: int = 200
    workspace_poses: int = 500
    random_draws: int = 5
    ridge: float = 1e-6
    rtol: float = 1e-8
    compare_single_anchors: bool = True
    anchors_nuisance: bool = True
    criterion: str = "tcp"

    def validate(self, n_anchors: int) -> None:
        """Raise ``ValueError`` naming the first bad option."""
        if self.n < 1:
            raise ValueError(f"n: must be at least 1, got {self.n}")
        if self.candidates < self.n:
            raise ValueError(f"candidates: {self.candidates} is fewer than n = {self.n}")
        lo, hi = self.extension_mm
        if not 0.0 <= lo < hi:
            raise ValueError(f"extension_mm: need 0 <= min < max, got {self.extension_mm}")
        if hi - lo <= 2.0 * self.anchor_uncertainty_mm:
            raise ValueError(
                f"anchor_uncertainty_mm: {self.anchor_uncertainty_mm} leaves no "
                f"extension range within {self.extension_mm}"
            )
        if self.anchor_uncertainty_mm < 0 or self.anchor_draws < 0:
            raise ValueError("anchor_uncertainty_mm and anchor_draws must be >= 0")
        if self.noise_mm <= 0:
            raise ValueError(f"noise_mm: must be > 0, got {self.noise_mm}")
        if len(self.joint_speed_deg_s) != 6 or min(self.joint_speed_deg_s) <= 0:
            raise ValueError(
                f"joint_speed_deg_s: need 6 positive speeds, got {self.joint_speed_deg_s}"
            )
        if self.dwell_s < 0:
            raise ValueError(f"dwell_s: must be >= 0, got {self.dwell_s}")
        if self.criterion not in ("tcp", "d"):
            raise ValueError(f"criterion: 'tcp' or 'd', got {self.criterion!r}")
        if self.offsets_mm is not None:
            if len(self.offsets_mm) != n_anchors:
                raise ValueError(
                    f"offsets_mm: {len(self.offsets_mm)} offsets for {n_anchors} anchors"
                )
            if any(c is not None and not math.isfinite(c) for c in self.offsets_mm):
                raise ValueError(f"offsets_mm: need finite offsets, got {self.offsets_mm}")
        if self.anchor_ids is not None and len(self.anchor_ids) != n_anchors:
            raise ValueError(f"anchor_ids: {len(self.anchor_ids)} ids for {n_anchors} anchors")
