"""Known-truth calibration problems: a true robot, a true anchor, poses and noisy lengths.

Used by the tests, the benchmarks and the emulated cell (``simulator/``). Everything is seeded
with :func:`numpy.random.default_rng`; nothing here reads or writes files.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.cable import N_DH, N_KIN, ParamLayout, predict_lengths
from calib.kinematics import N_JOINTS, FloatArray, IndexArray, forward_position
from calib.models import POSE_CLIP_DEG, RobotModel
from calib.sample_fields import DEFAULT_ANCHOR

#: The paper's Table XII, dataset D1: deviations identified by UKF-VSLM on the HSR JR680.
#: Shape (6, 4), per joint ``(dalpha_deg, da_mm, dd_mm, dtheta_deg)``.
TABLE_XII_D1 = np.array(
    [
        [0.0269, 0.4844, 0.7634, 0.0184],
        [0.0466, -2.2899, 0.6757, 0.0796],
        [0.0178, 0.3950, -0.1619, -0.0037],
        [0.0526, -0.5009, 1.4994, 0.0199],
        [-0.0648, 3.6568, 0.6200, -0.0571],
        [-0.1759, -1.4166, 0.7177, -0.0092],
    ]
)

#: Default cable range of the HY150-2000 sensor [mm].
CABLE_RANGE_MM = (0.0, 2000.0)


def dh_errors_internal(errors_deg_mm: FloatArray) -> FloatArray:
    """Convert a ``(6, 4)`` table of ``(dalpha_deg, da_mm, dd_mm, dtheta_deg)`` to the
    internal ``(24,)`` joint-major vector in rad and mm."""
    out = np.array(errors_deg_mm, dtype=float).reshape(N_JOINTS, 4)
    out[:, [0, 3]] = np.deg2rad(out[:, [0, 3]])
    return out.reshape(-1)


@dataclass(frozen=True)
class TrueCell:
    """The ground truth of an (emulated) cell.

    Attributes
    ----------
    model : RobotModel
        Nominal model the identification starts from.
    theta : ndarray, shape (p,)
        True full parameter vector (see :mod:`calib.cable`), for ``layout``.
    layout : ParamLayout
    """

    model: RobotModel
    theta: FloatArray
    layout: ParamLayout

    def lengths_mm(self, q_deg: FloatArray, anchor_index: IndexArray | None = None) -> FloatArray:
        """True (noise-free) indicator readings, shape (n,) [mm], for poses ``(n, 6)`` [deg]."""
        q = np.atleast_2d(np.asarray(q_deg, dtype=float))
        idx = np.zeros(q.shape[0], dtype=int) if anchor_index is None else anchor_index
        return predict_lengths(self.model, self.theta, self.model.table_rad(q), idx)

    def tool_positions_mm(self, q_deg: FloatArray) -> FloatArray:
        """True positions of the cable hook point, shape (n, 3) [mm]."""
        dh = self.model.dh_internal() + self.theta[:N_DH].reshape(N_JOINTS, 4)
        tool = self.model.tool_mm + self.theta[N_DH:N_KIN]
        q = self.model.table_rad(np.atleast_2d(np.asarray(q_deg, dtype=float)))
        return forward_position(dh, q, tool, self.model.convention)


def make_true_cell(
    model: RobotModel,
    *,
    dh_errors_deg_mm: FloatArray | None = None,
    tool_error_mm: FloatArray | None = None,
    anchors_mm: FloatArray | None = None,
    offsets_mm: FloatArray | None = None,
    anchor_ids: tuple[str, ...] = (DEFAULT_ANCHOR,),
) -> TrueCell:
    """Build a true cell.

    Parameters
    ----------
    dh_errors_deg_mm : ndarray, shape (6, 4), optional
        True DH deviations ``(dalpha_deg, da_mm, dd_mm, dtheta_deg)``; default Table XII D1.
    tool_error_mm : ndarray, shape (3,), optional
        True tool point minus the model's nominal tool point; default ``(0.8, -0.5, 1.2)``.
    anchors_mm : ndarray, shape (m, 3), optional
        True P0 per anchor [mm]; default one anchor at ``(1400, 300, 200)``.
    offsets_mm : ndarray, shape (m,), optional
        Indicator zero offsets c [mm]; default ``-350`` (the indicator was zeroed with
        350 mm of cable out).
    """
    layout = ParamLayout(anchor_ids)
    m = len(anchor_ids)
    errors = TABLE_XII_D1 if dh_errors_deg_mm is None else np.asarray(dh_errors_deg_mm)
    tool = np.array([0.8, -0.5, 1.2]) if tool_error_mm is None else np.asarray(tool_error_mm)
    if anchors_mm is None:
        anchors_mm = np.tile([1400.0, 300.0, 200.0], (m, 1)) + 250.0 * np.arange(m)[:, None]
    if offsets_mm is None:
        offsets_mm = np.full(m, -350.0)
    theta = np.zeros(layout.size)
    theta[:N_DH] = dh_errors_internal(errors)
    theta[N_DH:N_KIN] = tool
    for k in range(m):
        theta[layout.anchor_slice(k)] = [*np.asarray(anchors_mm)[k], np.asarray(offsets_mm)[k]]
    return TrueCell(model=model, theta=theta, layout=layout)


def random_poses_deg(
    cell: TrueCell,
    n: int,
    rng: np.random.Generator,
    *,
    spread_deg: float | None = None,
    centre_deg: FloatArray | None = None,
    anchor_index: int = 0,
    max_tries: int = 200,
) -> FloatArray:
    """Random poses within joint limits whose cable length stays in the sensor's range.

    Parameters
    ----------
    n : int
        Number of poses.
    spread_deg : float, optional
        When given, poses are drawn uniformly within ``centre ± spread`` (clipped to the
        limits) instead of over the full joint range: a local campaign.
    centre_deg : ndarray, shape (6,), optional
        Centre of a local campaign; default the middle of the joint limits.

    Returns
    -------
    ndarray, shape (n, 6)
        Joint angles [deg] whose true reading is within 50..1950 mm and whose hook point is
        300..1950 mm from the anchor (the cable's extension stays within the stroke).
    """
    limits = cell.model.limits_deg()
    # Realistic calibration poses avoid full-turn wrist angles: clip to ±POSE_CLIP_DEG, except
    # joints whose whole range lies outside it (the JR680's q3 reads 60..300 deg).
    clip = POSE_CLIP_DEG
    lo = np.where(limits[:, 0] < -clip, -clip, limits[:, 0])
    hi = np.where(limits[:, 1] > clip, np.maximum(clip, lo + 1.0), limits[:, 1])
    hi = np.where(limits[:, 0] > 0.0, limits[:, 1], hi)
    if spread_deg is not None:
        centre = (lo + hi) / 2 if centre_deg is None else np.asarray(centre_deg, dtype=float)
        lo, hi = np.maximum(lo, centre - spread_deg), np.minimum(hi, centre + spread_deg)
    out = np.empty((0, N_JOINTS))
    idx_anchor = cell.layout.anchor_slice(anchor_index)
    p0 = cell.theta[idx_anchor][:3]
    offset = cell.theta[idx_anchor][3]
    for _ in range(max_tries):
        cand = rng.uniform(lo, hi, size=(4 * n, N_JOINTS))
        dist = np.linalg.norm(cell.tool_positions_mm(cand) - p0, axis=1)
        length = dist + offset
        # The reading (dist + offset) must be on the meter's scale, and the cable's real
        # extension (dist) within the sensor's stroke: a negative offset does not lengthen it.
        ok = (length > CABLE_RANGE_MM[0] + 50) & (length < CABLE_RANGE_MM[1] - 50)
        ok &= (dist > 300) & (dist < CABLE_RANGE_MM[1] - 50)
        out = np.vstack([out, cand[ok]])
        if out.shape[0] >= n:
            return out[:n]
    raise ValueError(f"could not find {n} poses within the cable range after {max_tries} tries")


def noisy_lengths(
    cell: TrueCell,
    q_deg: FloatArray,
    rng: np.random.Generator,
    *,
    noise_mm: float = 0.05,
    anchor_index: IndexArray | None = None,
) -> FloatArray:
    """True lengths plus Gaussian noise of ``noise_mm`` [mm] (1σ), shape (n,)."""
    clean = cell.lengths_mm(q_deg, anchor_index)
    return clean + rng.normal(0.0, noise_mm, size=clean.shape)
