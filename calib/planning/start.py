"""The anchors of a plan: their ids, and P0 and the zero offset of those that start samples
already measured (multilateration with the nominal model)."""

from __future__ import annotations

from calib.cable import multilaterate
from calib.dataset import SampleSet
from calib.kinematics import FloatArray, forward_position
from calib.models import RobotModel
from calib.sample_fields import DEFAULT_ANCHOR


def plan_anchor_ids(anchor_ids: tuple[str, ...] | None, n_anchors: int) -> tuple[str, ...]:
    """The ids of a plan's anchors: ``anchor_ids`` as given, else ``A, B, …``."""
    return anchor_ids or tuple(chr(ord(DEFAULT_ANCHOR) + k) for k in range(n_anchors))


def start_offsets_mm(
    model: RobotModel, start: SampleSet, ids: tuple[str, ...]
) -> tuple[float | None, ...] | None:
    """The zero offset [mm] of each of the plan's anchors ``ids`` that the start samples
    measured (multilateration, :func:`start_anchor_fits`), None for the others; None when
    they measured none (:attr:`PlanOptions.offsets_mm`)."""
    fits = start_anchor_fits(model, start)
    out = tuple(float(fits[a][1]) if a in fits else None for a in ids)
    return out if any(c is not None for c in out) else None


def start_anchors_mm(model: RobotModel, start: SampleSet) -> dict[str, FloatArray]:
    """P0 of each start anchor by multilateration with the nominal model, each (3,) [mm]
    (the anchor guess for planning more poses at a sensor that has not moved)."""
    return {aid: p0 for aid, (p0, _) in start_anchor_fits(model, start).items()}


def start_anchor_fits(model: RobotModel, start: SampleSet) -> dict[str, tuple[FloatArray, float]]:
    """P0 (3,) [mm] and the indicator's zero offset [mm] of each start anchor, by
    multilateration with the nominal model."""
    pos = forward_position(
        model.dh_internal(), model.table_rad(start.joints_deg), model.tool_mm, model.convention
    )
    idx = start.anchor_index()
    return {
        aid: multilaterate(pos[idx == k], start.length_mm[idx == k])
        for k, aid in enumerate(start.anchor_ids)
    }
