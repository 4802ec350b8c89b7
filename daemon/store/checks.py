"""Hold checks: each robot's check poses and the history of its checks.

A check captures the robot's check poses into a campaign of its own and compares the lengths
with the accepted calibration's predictions (:mod:`daemon.monitors.holdcheck`). The store keeps:

- ``check_poses``: the poses chosen by the user (``PUT /robots/{id}/check-poses``), one row
  per robot; absent: the daemon picks well-spread poses of the calibration's samples.
- ``checks``: one row per check: the robot, its campaign, the result it was compared with,
  ``trigger`` (manual | schedule), ``status`` (running | ok | not_held | failed), the figures
  (``rms_mm``, ``mae_mm``, ``max_mm``, ``n``) and the ``threshold_mm`` it was judged by.

Timestamps are seconds since the Unix epoch (UTC); joint angles are degrees.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from typing import Any, Final, Literal, cast

from typing_extensions import TypedDict

from daemon.store.db import Row, StoreDB, decode_row, last_id, now, to_json
from daemon.store.errors import StoreInvalid
from daemon.store.rows import CHECK_STATUSES, CHECK_TRIGGERS, CheckStatus

#: Largest number of check poses a robot may have.
MAX_CHECK_POSES: Final = 100


class CheckRow(TypedDict):
    """One hold check (see the module docstring)."""

    id: int
    robot_id: int
    campaign_id: int
    result_id: int
    trigger: str
    status: CheckStatus
    refit_anchor: bool
    threshold_mm: float
    rms_mm: float | None
    mae_mm: float | None
    max_mm: float | None
    n: int | None
    error: str | None
    started_at: float
    finished_at: float | None
    poses_deg: list[list[float]]
    detail: dict[str, Any] | None


class CheckPoses(TypedDict):
    """A robot's check poses [deg] and where they come from (``user`` or ``default``)."""

    robot_id: int
    source: Literal["user", "default"]
    poses_deg: list[list[float]]
    updated_at: float | None


def validate_poses(poses_deg: Sequence[Sequence[float]]) -> list[list[float]]:
    """Poses as a list of 6-lists of finite floats [deg], 1 to :data:`MAX_CHECK_POSES`.

    Raises
    ------
    StoreInvalid
        Naming the pose (1-based) and joint.
    """
    if not 1 <= len(poses_deg) <= MAX_CHECK_POSES:
        raise StoreInvalid(f"poses_deg: expected 1..{MAX_CHECK_POSES} poses, got {len(poses_deg)}")
    out = []
    for i, pose in enumerate(poses_deg, start=1):
        if len(pose) != 6:
            raise StoreInvalid(f"poses_deg pose {i}: expected 6 joint angles, got {len(pose)}")
        row = [float(v) for v in pose]
        for j, v in enumerate(row, start=1):
            if not math.isfinite(v):
                raise StoreInvalid(f"poses_deg pose {i}, q{j}: not finite")
        out.append(row)
    return out


def _check_row(row: Row) -> CheckRow:
    out = decode_row(row)
    out["refit_anchor"] = bool(out["refit_anchor"])
    out["poses_deg"] = json.loads(out.pop("poses_json"))
    return cast(CheckRow, out)


class CheckStore(StoreDB):
    """Check poses and hold checks (part of :class:`daemon.store.Store`)."""

    # ------------------------------------------------------------------ check poses
    def set_check_poses(self, robot_id: int, poses_deg: Sequence[Sequence[float]]) -> CheckPoses:
        """Store the user's check poses of a robot (replacing any).

        Raises
        ------
        StoreNotFound
        StoreInvalid
        """
        poses = validate_poses(poses_deg)
        with self._write():
            self._require("robots", "robot", robot_id)
            self._table("check_poses").upsert(
                {
                    "robot_id": robot_id,
                    "poses_json": to_json(poses, "poses_deg"),
                    "updated_at": now(),
                },
                pk="robot_id",
            )
        return {"robot_id": robot_id, "source": "user", "poses_deg": poses, "updated_at": now()}

    def user_check_poses(self, robot_id: int) -> CheckPoses | None:
        """The user's check poses, or None when none are set."""
        row = self._one("SELECT * FROM check_poses WHERE robot_id = ?", [robot_id])
        if row is None:
            return None
        poses = json.loads(row["poses_json"])
        return {
            "robot_id": robot_id,
            "source": "user",
            "poses_deg": poses,
            "updated_at": row["updated_at"],
        }

    def clear_check_poses(self, robot_id: int) -> None:
        """Forget the user's check poses (the default applies again)."""
        with self._write():
            self.conn.execute("DELETE FROM check_poses WHERE robot_id = ?", [robot_id])

    # ------------------------------------------------------------------ checks
    def create_check(
        self,
        robot_id: int,
        campaign_id: int,
        result_id: int,
        *,
        trigger: str,
        threshold_mm: float,
        refit_anchor: bool,
        poses_deg: Sequence[Sequence[float]],
    ) -> CheckRow:
        """A new check, status ``running``.

        Raises
        ------
        StoreNotFound
            No such robot, campaign or result.
        StoreInvalid
            Unknown trigger, threshold not positive, bad poses.
        """
        if trigger not in CHECK_TRIGGERS:
            raise StoreInvalid(f"trigger: must be one of {CHECK_TRIGGERS}, got {trigger!r}")
        if not (math.isfinite(threshold_mm) and threshold_mm > 0):
            raise StoreInvalid(f"threshold_mm: must be positive, got {threshold_mm!r}")
        poses = validate_poses(poses_deg)
        with self._write():
            self._require("robots", "robot", robot_id)
            self._require("campaigns", "campaign", campaign_id)
            self._require("results", "result", result_id)
            table = self._table("checks").insert(
                {
                    "robot_id": robot_id,
                    "campaign_id": campaign_id,
                    "result_id": result_id,
                    "trigger": trigger,
                    "status": "running",
                    "refit_anchor": bool(refit_anchor),
                    "threshold_mm": float(threshold_mm),
                    "rms_mm": None,
                    "mae_mm": None,
                    "max_mm": None,
                    "n": None,
                    "error": None,
                    "started_at": now(),
                    "finished_at": None,
                    "poses_json": to_json(poses, "poses_deg"),
                    "detail_json": None,
                }
            )
            return self.check(last_id(table))

    def finish_check(
        self,
        check_id: int,
        status: CheckStatus,
        *,
        metrics: dict[str, float] | None = None,
        error: str | None = None,
        detail: dict[str, Any] | None = None,
    ) -> CheckRow:
        """Close a check: ``ok`` or ``not_held`` with ``metrics`` (``n, rmse_mm, mae_mm,
        max_mm``), or ``failed`` with an ``error``.

        Raises
        ------
        StoreNotFound
        StoreInvalid
            Unknown or non-terminal status.
        """
        if status not in CHECK_STATUSES or status == "running":
            raise StoreInvalid(f"status: must be ok, not_held or failed, got {status!r}")
        m = metrics or {}
        updates: Row = {
            "status": status,
            "finished_at": now(),
            "error": error,
            "rms_mm": m.get("rmse_mm"),
            "mae_mm": m.get("mae_mm"),
            "max_mm": m.get("max_mm"),
            "n": None if m.get("n") is None else int(m["n"]),
        }
        if detail is not None:
            updates["detail_json"] = to_json(detail, "detail")
        with self._write():
            self._require("checks", "check", check_id)
            self._table("checks").update(check_id, updates)
            return self.check(check_id)

    def check(self, check_id: int) -> CheckRow:
        """A check row.

        Raises
        ------
        StoreNotFound
        """
        return _check_row(self._require("checks", "check", check_id))

    def check_of_campaign(self, campaign_id: int) -> CheckRow | None:
        """The check whose own campaign ``campaign_id`` is, or None (an operator's campaign)."""
        rows = self._query("SELECT id FROM checks WHERE campaign_id = ? LIMIT 1", [campaign_id])
        return self.check(int(rows[0]["id"])) if rows else None

    def list_checks(
        self, robot_id: int | None = None, limit: int = 100, status: str | None = None
    ) -> list[CheckRow]:
        """The newest ``limit`` checks (all robots or one, any or one status), oldest first.

        Raises
        ------
        StoreInvalid
            ``limit`` outside 1..10000.
        """
        rows = self._page(
            "SELECT * FROM checks",
            [("robot_id = ?", robot_id), ("status = ?", status)],
            limit=limit,
            newest=True,
        )
        return [_check_row(r) for r in rows]

    def fail_running_checks(self, reason: str) -> int:
        """Mark every running check failed (at start-up: a stopped daemon left them)."""
        with self._write():
            cur = self.conn.execute(
                "UPDATE checks SET status = 'failed', error = ?, finished_at = ? "
                "WHERE status = 'running'",
                (reason, now()),
            )
            return int(cur.rowcount)
