"""Pose plans of campaigns (``POST /campaigns/{id}/plan``) and their progress.

A plan is stored whole, as JSON: the options it was made with, its summary
(:meth:`calib.planning.PlanResult.to_json`) and its poses (``PlanResult.csv_rows``: ``pose``,
``q1..q6`` [deg], ``anchor``, ``extension_mm``, ``anchor_x_mm..anchor_z_mm``). A campaign may
be planned again; :meth:`PlanStore.latest_plan` is the newest.

Progress is not stored: :func:`calib.planning.progress.match_poses` computes it from the
campaign's samples each time it is asked (see its docstring for why that is enough).
"""

from __future__ import annotations

import json
from typing import Any, cast

from typing_extensions import TypedDict

from calib.dataset import JOINT_COLUMNS
from daemon.store.db import Row, StoreDB, decode_row, last_id, now, to_json
from daemon.store.errors import StoreInvalid, StoreNotFound
from daemon.store.rows import JointsDeg


class _PoseNumber(TypedDict):
    pose: int


class PlannedPoseRow(_PoseNumber, JointsDeg):
    """A planned pose as :meth:`calib.planning.PlanResult.csv_rows` gives it: ``pose``,
    joints ``q1..q6`` [deg], anchor id, predicted cable extension and the anchor guess [mm]."""

    anchor: str
    extension_mm: float
    anchor_x_mm: float
    anchor_y_mm: float
    anchor_z_mm: float


class PlanHeader(TypedDict):
    """What a stored plan is, apart from its poses: ``options`` as requested, ``summary``
    (condition number, 1σ per base parameter, TCP σ plan vs random, times, anchor gain)."""

    id: int
    campaign_id: int
    robot_id: int
    created_at: float
    options: dict[str, Any]
    summary: dict[str, Any]


class PlanRow(PlanHeader):
    """A stored plan with its poses in visiting order."""

    poses: list[PlannedPoseRow]


def _plan_out(row: Row) -> PlanRow:
    out = decode_row(row)
    out["summary"] = json.loads(out.pop("summary_json"))
    out["poses"] = json.loads(out.pop("poses_json"))
    return cast(PlanRow, out)


class PlanStore(StoreDB):
    """Plans (part of :class:`daemon.store.Store`)."""

    def save_plan(
        self,
        campaign_id: int,
        options: dict[str, Any],
        summary: dict[str, Any],
        poses: list[dict[str, Any]],
    ) -> PlanRow:
        """Store a plan of campaign ``campaign_id`` (made for the campaign's robot).

        Raises
        ------
        StoreNotFound
            No such campaign.
        StoreInvalid
            No poses, or a pose without ``q1..q6`` or ``anchor``.
        """
        if not poses:
            raise StoreInvalid("poses: a plan needs at least one pose")
        for i, pose in enumerate(poses):
            missing = [k for k in (*JOINT_COLUMNS, "anchor") if k not in pose]
            if missing:
                raise StoreInvalid(f"poses[{i}]: missing {', '.join(missing)}")
        with self._write():
            campaign = self._require("campaigns", "campaign", campaign_id)
            table = self._table("plans").insert(
                {
                    "campaign_id": campaign_id,
                    "robot_id": int(campaign["robot_id"]),
                    "options_json": to_json(options, "options"),
                    "summary_json": to_json(summary, "summary"),
                    "poses_json": to_json(poses, "poses"),
                    "created_at": now(),
                }
            )
            row = self._get("plans", last_id(table))
        assert row is not None
        return _plan_out(row)

    def latest_plan(self, campaign_id: int) -> PlanRow:
        """The newest plan of the campaign.

        Raises
        ------
        StoreNotFound
            No such campaign (``campaign 3: not found``), or it has no plan (``campaign 3: no
            plan yet``).
        """
        self._require("campaigns", "campaign", campaign_id)
        row = self._one(
            "SELECT * FROM plans WHERE campaign_id = ? ORDER BY id DESC LIMIT 1", [campaign_id]
        )
        if row is None:
            raise StoreNotFound("campaign", campaign_id, "no plan yet")
        return _plan_out(row)
