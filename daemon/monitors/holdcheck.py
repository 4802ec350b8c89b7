"""Hold checks: is the robot still the one its accepted calibration describes?

Every surface calls them hold checks: the ``[hold_check]`` settings, ``POST
/robots/{id}/checks``, the ``hold_check`` and ``hold_check_not_held`` events, the
``cablecal_hold_check_*`` gauges, the ``hold_check`` block of ``GET /status``, the logger
``cablecal.hold_check``; "drift" is only :mod:`calib.drift`, the measurement drifting within
one campaign. The numeric decisions are
pure, in :mod:`calib.monitor.holdcheck`; this module holds the store, the sampler, the
schedule and the events.

The flow
    1. A robot with an accepted calibration has **check poses**: the user's
       (``PUT /robots/{id}/check-poses``), else :func:`calib.monitor.holdcheck.spread_indices`
       picks
       ``hold_check.n_poses`` (8) well-spread poses of the accepted calibration's own samples.
    2. A check starts on ``POST /robots/{id}/checks`` or every ``hold_check.check_interval_h``
       (default off). It creates a campaign ``check <n> of robot <id>`` and switches the
       sampler's auto capture to it (not persisted: a restart fails the running check instead
       of capturing on). The robot must now visit the check poses: a robot program on a real
       cell, ``load_poses`` on the EMULATED cell's control port (``cablecal simulate``), or
       manual captures into the check campaign. A capture counts for the check pose it is
       within ``hold_check.pose_tol_deg`` of (every joint).
    3. When every check pose has a capture (or ``hold_check.timeout_s`` passes: status ``failed``),
       the captures are compared with the calibration's predictions by
       :func:`calib.verify.verify` — **without** refitting the anchor by default: the sensor
       stays mounted between checks, and refitting four parameters per anchor on 8 poses
       would absorb part of a real change. Set ``hold_check.refit_anchor = true`` after moving the
       sensor (it needs at least 5 poses per anchor).
    4. :func:`calib.monitor.holdcheck.judge`: ``not_held`` when the RMS exceeds the threshold
       (:func:`calib.monitor.holdcheck.threshold_mm`: ``hold_check.threshold_mm``, else
       ``hold_check.threshold_factor`` (3) × the calibration's own residual RMSE, never below
       ``hold_check.min_threshold_mm``).
       The check row, a ``hold_check_not_held`` (or ``hold_check``) event, the gauges
       ``cablecal_hold_check_rms_mm`` and ``cablecal_hold_check_threshold_mm`` and the
       ``hold_check`` block of ``GET /status`` show it. A not-held event names its likely
       cause: a moved sensor (a point shift of P0 changes lengths by ``−u·δ``, ``u`` the
       cable direction) or a robot change (a joint's zero offset), whichever fits the
       residuals better (:func:`calib.monitor.stepwatch.explain_change`; ``unclear`` when the
       poses cannot tell).

``calib`` is imported inside the functions that use it.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from typing import TYPE_CHECKING, Any

from calib.result import CalibrationResult
from daemon import metrics
from daemon.store.rows import CHECK_JUDGED

if TYPE_CHECKING:
    from daemon.config import HoldCheckSettings
    from daemon.store import CheckPoses, CheckRow, Store
    from daemon.store.rows import CheckStatus

log = logging.getLogger("cablecal.hold_check")

#: The event of a finished or skipped check, and of a check whose robot no longer holds its
#: calibration (before 0.2.0: ``drift_check`` and ``drift``; schema migration 8 renamed the
#: stored ones).
EVENT_CHECK = "hold_check"
EVENT_NOT_HELD = "hold_check_not_held"

#: Seconds between looks at a running check's captures.
POLL_S = 0.5


class CheckConflict(RuntimeError):
    """A check cannot start now (another check runs, or auto capture is on elsewhere)."""


# ------------------------------------------------------------------ store-level helpers
def check_poses(store: Store, robot_id: int, n_poses: int) -> CheckPoses:
    """The robot's check poses: the user's, else ``n_poses`` spread poses of the accepted
    calibration's campaign samples (:func:`calib.monitor.holdcheck.spread_indices`).

    Raises
    ------
    daemon.store.StoreNotFound
        No such robot, or (default poses) no accepted calibration.
    """
    user = store.user_check_poses(robot_id)
    if user is not None:
        store.robot(robot_id)
        return user
    from calib.monitor.holdcheck import spread_indices

    result = store.accepted_result(robot_id)
    samples, _ = store.sample_set(int(result["campaign_id"]))
    q = samples.joints_deg
    rows = spread_indices(q, n_poses)
    return {
        "robot_id": robot_id,
        "source": "default",
        "poses_deg": [[float(v) for v in q[i]] for i in rows],
        "updated_at": None,
    }


# ------------------------------------------------------------------ the monitor
class HoldCheckMonitor:
    """Runs hold checks in the daemon: one at a time, manual or scheduled.

    Parameters
    ----------
    store : Store
    settings : HoldCheckSettings
    auto : daemon.monitors.autocapture.AutoCapture or None
        Auto capture's owner (a check captures its campaign in auto mode); None: captures
        come from ``POST /campaigns/{id}/captures`` only.
    """

    def __init__(self, store: Store, settings: HoldCheckSettings, auto: Any = None) -> None:
        self.store = store
        self.settings = settings
        self.auto = auto
        self._task: asyncio.Task[None] | None = None
        self._running: CheckRow | None = None
        self._schedule: asyncio.Task[None] | None = None
        #: The newest finished check (any robot), kept here so ``status()`` (``GET /status``,
        #: polled) never queries SQLite; None before the first check. The monitor is the only
        #: writer of finished checks (``_finish``, and ``start`` failing leftovers), so it is
        #: exact once loaded.
        self._last: CheckRow | None = None
        self._last_loaded = False

    async def start(self) -> None:
        """Fail checks a stopped daemon left running; start the schedule if configured."""
        n = self.store.fail_running_checks("interrupted by daemon restart")
        if n:
            log.warning("failed %d check(s) left running", n)
        checks = self.store.list_checks(limit=1000)
        for check in checks:
            if check["status"] in CHECK_JUDGED and check["rms_mm"] is not None:
                metrics.record_hold_check(check["robot_id"], check["rms_mm"], check["threshold_mm"])
        self._remember_last(checks)
        if self.settings.check_interval_h:
            self._schedule = asyncio.create_task(self._scheduled(), name="hold-check-schedule")

    async def stop(self) -> None:
        """Cancel the schedule and a running check (it is marked failed)."""
        for task in (self._schedule, self._task):
            if task is not None:
                task.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await task

    @property
    def running(self) -> CheckRow | None:
        """The check now running, or None."""
        return self._running

    def start_check(self, robot_id: int, trigger: str = "manual") -> CheckRow:
        """Create the check campaign and row and start capturing; returns the row.

        Raises
        ------
        CheckConflict
            A check is running, or auto capture is on for another campaign.
        daemon.store.StoreNotFound
            No such robot, or no accepted calibration.
        ValueError
            No threshold can be derived (see :func:`calib.monitor.holdcheck.threshold_mm`).
        """
        if self._running is not None:
            raise CheckConflict(f"check {self._running['id']} is running")
        busy = None if self.auto is None else self.auto.campaign_id
        if busy is not None:
            raise CheckConflict(f"auto capture is on for campaign {busy}; switch it off first")
        result_row = self.store.accepted_result(robot_id)
        result = result_row["result"]
        from calib.monitor.holdcheck import threshold_mm
        from calib.verify import reference_rmse_mm

        cfg = self.settings
        limit = threshold_mm(
            reference_rmse_mm(result), cfg.threshold_mm, cfg.threshold_factor, cfg.min_threshold_mm
        )
        poses = check_poses(self.store, robot_id, self.settings.n_poses)["poses_deg"]
        n = len(self.store.list_checks(robot_id, limit=10_000)) + 1
        campaign = self.store.create_campaign(
            f"check {n} of robot {self.store.robot(robot_id)['name']}",
            robot_id,
            f"hold check ({trigger}) against result {result_row['id']}",
        )
        cid = int(campaign["id"])
        check = self.store.create_check(
            robot_id,
            cid,
            int(result_row["id"]),
            trigger=trigger,
            threshold_mm=limit,
            refit_anchor=self.settings.refit_anchor,
            poses_deg=poses,
        )
        if self.auto is not None:
            self.auto.start_check(cid, anchor=CalibrationResult.from_json(result).first_anchor)
        self._running = check
        self._task = asyncio.create_task(self._follow(check, result), name="hold-check")
        log.info("hold check started", extra={"campaign_id": cid, "check_id": check["id"]})
        return check

    async def _follow(self, check: CheckRow, result: dict[str, Any]) -> None:
        from calib.monitor.holdcheck import covered, evaluate

        cid, deadline = check["campaign_id"], time.monotonic() + self.settings.timeout_s
        poses = check["poses_deg"]
        try:
            while True:
                samples, _ = self.store.sample_set(cid)
                near = covered(poses, samples.joints_deg, self.settings.pose_tol_deg)
                if near.all():
                    break
                if time.monotonic() > deadline:
                    self._finish(
                        check,
                        "failed",
                        error=f"timed out after "
                        f"{self.settings.timeout_s:g} s: {int(near.sum())} of "
                        f"{len(near)} check poses captured",
                    )
                    return
                await asyncio.sleep(POLL_S)
            self._release(cid)
            ev = await asyncio.to_thread(
                evaluate, result, samples, check["threshold_mm"], check["refit_anchor"]
            )
            self._finish(check, ev.status, metrics_=ev.metrics, detail=ev.detail)
        except asyncio.CancelledError:
            self._finish(check, "failed", error="cancelled (daemon stopping)")
            raise
        except Exception as exc:
            log.exception("hold check failed", extra={"check_id": check["id"]})
            self._finish(check, "failed", error=f"{type(exc).__name__}: {exc}")

    def _release(self, campaign_id: int) -> None:
        if self.auto is not None:
            self.auto.release(campaign_id)

    def _finish(
        self,
        check: CheckRow,
        status: CheckStatus,
        *,
        metrics_: dict[str, float] | None = None,
        error: str | None = None,
        detail: dict[str, Any] | None = None,
    ) -> None:
        self._release(check["campaign_id"])
        self._running = None
        row = self.store.finish_check(
            check["id"], status, metrics=metrics_, error=error, detail=detail
        )
        self._last, self._last_loaded = row, True
        robot = check["robot_id"]
        if status == "failed":
            message = f"check {row['id']} of robot {robot} failed: {error}"
        else:
            metrics.record_hold_check(
                robot, float(row["rms_mm"] or 0.0), float(row["threshold_mm"])
            )
            message = (
                f"check {row['id']} of robot {robot}: RMS {row['rms_mm']:.4f} mm, "
                f"threshold {row['threshold_mm']:.4f} mm: {status}"
            )
            explained = (detail or {}).get("explanation")
            if status == "not_held" and explained is not None:
                from calib.monitor.holdcheck import explanation_text

                message += f"; {explanation_text(explained)}"
        kind = EVENT_NOT_HELD if status == "not_held" else EVENT_CHECK
        self.store.record_event(
            kind,
            None,
            message,
            {
                "check_id": row["id"],
                "robot_id": robot,
                "status": status,
                "rms_mm": row["rms_mm"],
                "threshold_mm": row["threshold_mm"],
                "explanation": (detail or {}).get("explanation"),
            },
            campaign_id=check["campaign_id"],
        )
        (log.warning if status != "ok" else log.info)(message)

    async def _scheduled(self) -> None:
        """Every ``check_interval_h``: a check of each robot with an accepted calibration,
        one after the other; a robot that cannot be checked now is skipped (an event)."""
        from daemon.store import StoreNotFound

        period_s = float(self.settings.check_interval_h or 0) * 3600.0
        while True:
            await asyncio.sleep(period_s)
            for robot in self.store.list_robots():
                rid = int(robot["id"])
                try:
                    self.start_check(rid, "schedule")
                except StoreNotFound:
                    continue
                except (CheckConflict, ValueError) as exc:
                    message = f"scheduled check of robot {rid} skipped: {exc}"
                    self.store.record_event(EVENT_CHECK, None, message)
                    continue
                if self._task is not None:
                    with contextlib.suppress(Exception):
                        await self._task

    def _remember_last(self, checks: list[CheckRow]) -> None:
        """Keep the newest finished check of ``checks`` (oldest first) for :meth:`status`."""
        done = [c for c in checks if c["status"] != "running"]
        self._last, self._last_loaded = (done[-1] if done else None), True

    def status(self) -> dict[str, Any]:
        """The ``hold_check`` block of ``GET /status``: the last finished check (any robot)
        ``last_check_at`` [s epoch], ``rms_mm``, ``threshold_mm``, ``state`` (ok, not_held,
        failed, or none before the first check), ``robot_id``, ``check_id``, and
        ``running`` (the running check's id or None), ``check_interval_h``, ``error`` (why
        the last check failed) and ``cause`` (what moved when not held: :func:`_cause`).

        From memory: the last check is read from the store once (in :meth:`start`, or here on
        the first call without it) and replaced when :meth:`_finish` stores one, so a busy
        store (a capture or an import writing) never delays ``GET /status``."""
        if not self._last_loaded:
            self._remember_last(self.store.list_checks(limit=20))
        last = self._last
        return {
            "state": last["status"] if last else "none",
            "last_check_at": last["finished_at"] if last else None,
            "rms_mm": last["rms_mm"] if last else None,
            "threshold_mm": last["threshold_mm"] if last else None,
            "robot_id": last["robot_id"] if last else None,
            "check_id": last["id"] if last else None,
            "running": self._running["id"] if self._running else None,
            "check_interval_h": self.settings.check_interval_h,
            "error": last["error"] if last else None,
            "cause": _cause(last),
        }


def _cause(check: CheckRow | None) -> dict[str, Any] | None:
    """What moved, for a check judged ``not_held`` with an explanation: ``kind`` (sensor, robot,
    unclear), its figure (``shift_mm``: the stand's move [mm]; ``joint`` and
    ``joint_offset_deg``) and ``text`` (:func:`calib.monitor.holdcheck.explanation_text`,
    the one wording the event, the log and the page share); None otherwise."""
    if check is None or check["status"] != "not_held":
        return None
    explained = (check["detail"] or {}).get("explanation")
    if not explained:
        return None
    import math

    from calib.monitor.holdcheck import explanation_text

    shift = [float(v) for v in explained.get("anchor_shift_mm") or []]
    return {
        "kind": explained["kind"],
        "shift_mm": math.sqrt(sum(v * v for v in shift)) if shift else None,
        "joint": explained.get("joint"),
        "joint_offset_deg": explained.get("joint_offset_deg"),
        "text": explanation_text(explained),
    }
