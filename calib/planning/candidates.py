"""Candidate poses for planning: uniform within the joint limits, filtered by the cell.

A candidate pose is feasible for an anchor when

- every joint is within the model's ``limits_deg`` (the same convention ``identify`` reads);
- the cable extension ``|p − P0|`` (tool point ``p`` of the nominal model, anchor ``P0``) lies
  within ``extension_mm`` shrunk on both sides by ``margin_mm`` (the anchor guess's
  uncertainty: a pose planned at the guess must stay within the stroke at the true anchor);
- the flange origin and the tool point are above ``min_z_mm`` in the base frame;
- when the indicator's zero offset ``c`` at the anchor is known (the reading is
  ``|p − P0| + c``), the predicted reading lies within the indicator's range
  (:data:`calib.dataset.CABLE_MIN_MM` .. :data:`calib.dataset.CABLE_MAX_MM`) shrunk by
  :data:`calib.dataset.READING_MARGIN_MM` plus ``margin_mm``: a pose the indicator shows as
  over or under range cannot be captured.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from calib.dataset import CABLE_MAX_MM, CABLE_MIN_MM, READING_MARGIN_MM
from calib.kinematics import N_JOINTS, FloatArray, forward_frames, tool_position
from calib.models import RobotModel


def flange_and_tool_mm(model: RobotModel, q_deg: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Flange origin and tool point of the nominal model, each shape (n, 3) [mm]."""
    rot, origin = forward_frames(model.dh_internal(), model.table_rad(q_deg), model.convention)
    return origin[:, -1], tool_position(rot, origin, model.tool_mm)


def reading_window_mm(margin_mm: float = 0.0) -> tuple[float, float]:
    """The readings [mm] a plan may predict: the indicator's range shrunk by
    :data:`calib.dataset.READING_MARGIN_MM` plus ``margin_mm`` on both sides."""
    shrink = READING_MARGIN_MM + margin_mm
    return CABLE_MIN_MM + shrink, CABLE_MAX_MM - shrink


def feasible(
    model: RobotModel,
    q_deg: FloatArray,
    anchor_mm: FloatArray,
    extension_mm: tuple[float, float],
    min_z_mm: float,
    margin_mm: float = 0.0,
    offset_mm: float | None = None,
) -> tuple[FloatArray, FloatArray]:
    """Feasibility mask and cable extension of poses for one anchor.

    Parameters
    ----------
    q_deg : ndarray, shape (n, 6)
    anchor_mm : ndarray, shape (3,)
    offset_mm : float, optional
        The indicator's zero offset ``c`` at this anchor [mm] (reading = extension + c);
        None: unknown, the readings are not checked.

    Returns
    -------
    ok : ndarray of bool, shape (n,)
    extension_mm : ndarray, shape (n,)
        ``|p − P0|`` with the nominal model [mm].
    """
    limits = model.limits_deg()
    ok = np.all((q_deg >= limits[:, 0]) & (q_deg <= limits[:, 1]), axis=1)
    flange, tool = flange_and_tool_mm(model, q_deg)
    ext = np.linalg.norm(tool - np.asarray(anchor_mm, dtype=float), axis=1)
    ok &= (ext >= extension_mm[0] + margin_mm) & (ext <= extension_mm[1] - margin_mm)
    if offset_mm is not None:
        lo, hi = reading_window_mm(margin_mm)
        reading = ext + offset_mm
        ok &= (reading >= lo) & (reading <= hi)
    ok &= (flange[:, 2] >= min_z_mm) & (tool[:, 2] >= min_z_mm)
    return ok, ext


def draw_candidates(
    model: RobotModel,
    anchors_mm: FloatArray,
    n: int,
    rng: np.random.Generator,
    extension_mm: tuple[float, float],
    min_z_mm: float,
    margin_mm: float = 0.0,
    max_batches: int = 200,
    offsets_mm: Sequence[float | None] | None = None,
) -> tuple[FloatArray, FloatArray]:
    """``n`` feasible (pose, anchor) candidates, spread evenly over the anchors.

    Parameters
    ----------
    anchors_mm : ndarray, shape (m, 3)
    n : int
        Candidates in total; each anchor gets ``n // m`` (the first ones one more).
    offsets_mm : sequence of m (float or None), optional
        The indicator's zero offset per anchor [mm] (:func:`feasible`); None: unknown.

    Returns
    -------
    q_deg : ndarray, shape (n, 6)
    anchor_index : ndarray of int, shape (n,)

    Raises
    ------
    ValueError
        When an anchor has too few feasible poses (anchor out of reach, floor too high).
    """
    limits = model.limits_deg()
    m = anchors_mm.shape[0]
    qs, idx = [], []
    for k in range(m):
        want = n // m + (1 if k < n % m else 0)
        offset = None if offsets_mm is None else offsets_mm[k]
        got = np.empty((0, N_JOINTS))
        for _ in range(max_batches):
            q = rng.uniform(limits[:, 0], limits[:, 1], size=(max(2 * want, 64), N_JOINTS))
            ok, _ = feasible(model, q, anchors_mm[k], extension_mm, min_z_mm, margin_mm, offset)
            got = np.vstack([got, q[ok]])
            if got.shape[0] >= want:
                break
        if got.shape[0] < want:
            lo, hi = reading_window_mm(margin_mm)
            reading = (
                f" and a reading within {lo:.0f}..{hi:.0f} mm at zero offset {offset:.1f} mm"
                if offset is not None
                else ""
            )
            raise ValueError(
                f"anchor {k + 1} at {anchors_mm[k].tolist()} mm: only {got.shape[0]} of {want} "
                f"random poses reach it within the cable extension {extension_mm} mm "
                f"(margin {margin_mm} mm){reading} above z = {min_z_mm} mm"
            )
        qs.append(got[:want])
        idx.append(np.full(want, k))
    return np.vstack(qs), np.concatenate(idx)
