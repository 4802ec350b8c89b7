"""Live sensor watch: after each new sample, did the drawstring sensor move?

The flow (the decisions are pure, in :mod:`calib.monitor.running_fit` and
:mod:`calib.monitor.stepwatch`; this module holds the queue, the store and the events):

1. The sampler's sink is wrapped (:meth:`SensorWatch.wrap`): every stored capture is queued
   for its campaign, and one task per campaign takes them in order, off the event loop.
2. The campaign's :class:`calib.monitor.running_fit.LiveTester` predicts the new sample's
   cable length with its running fit (refitted in a worker thread as the campaign grows) and
   tests the residual (:class:`calib.monitor.stepwatch.StepDetector`).
3. On an alarm the step is located among the recent samples
   (:meth:`calib.monitor.running_fit.LiveTester.locate`); every sample of the session from it
   on goes to a new anchor session (:func:`calib.monitor.stepwatch.next_anchor`; one still in
   flight when auto capture switched follows), auto capture goes on with it, and the event
   ``sensor_moved`` (size, first sample id and row, the moved sample ids), the counter
   ``cablecal_sensor_moved_total`` and the ``watch`` block of ``GET /status`` (the page's
   banner) tell the operator, who can undo it (``POST /campaigns/{id}/sensor-moved/undo``:
   :meth:`SensorWatch.undo`).

``calib`` is imported inside the functions that use it.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from daemon import metrics

if TYPE_CHECKING:
    from calib.monitor.running_fit import LiveTester
    from calib.monitor.stepwatch import StepAlarm, StepSettings
    from daemon.sampler.capture import Capture, CaptureSink
    from daemon.store import Store

log = logging.getLogger("cablecal.watch")

SENSOR_MOVED = "sensor_moved"
SENSOR_MOVED_UNDONE = "sensor_moved_undone"


class NothingToUndo(LookupError):
    """The campaign has no automatic anchor split left to undo."""


@dataclass
class CampaignWatch:
    """The watch's state of one campaign."""

    campaign_id: int
    robot_id: int
    tester: LiveTester
    queue: list[dict[str, Any]] = field(default_factory=list)
    task: asyncio.Task[None] | None = None
    tested: int = 0
    last_residual_mm: float | None = None
    #: A move was just found: the next sample may have been in flight in the old session.
    after_move: bool = False


class WatchedSink:
    """A :class:`daemon.sampler.capture.CaptureSink` that tells the watch about each stored
    capture; refusals (with their pose) and device events go to the wrapped sink as they are.
    The sampler takes it as its sink when it is built
    (:func:`daemon.api.lifespan.default_sampler`)."""

    def __init__(self, inner: CaptureSink, watch: SensorWatch) -> None:
        self._inner = inner
        self._watch = watch

    def store_capture(self, campaign_id: int, capture: Capture) -> Mapping[str, Any]:
        row = self._inner.store_capture(campaign_id, capture)
        self._watch.saw_sample(campaign_id, dict(row))
        return row

    def record_rejection(
        self,
        campaign_id: int | None,
        reason: str,
        detail: str,
        device: str | None,
        joints_deg: Sequence[float] | None = None,
    ) -> None:
        self._inner.record_rejection(campaign_id, reason, detail, device, joints_deg)

    def record_event(
        self, kind: str, device: str | None, message: str, detail: dict[str, Any] | None = None
    ) -> None:
        self._inner.record_event(kind, device, message, detail)


class SensorWatch:
    """Watches every campaign's new samples for a moved sensor (see the module docstring).

    Parameters
    ----------
    store : Store
    settings : StepSettings
    enabled : bool

    It is built before the sampler, whose sink is :meth:`wrap`'s; :meth:`start` gives it auto
    capture's owner (:class:`daemon.monitors.autocapture.AutoCapture`, built on the sampler):
    a move takes auto capture to the new anchor.
    """

    def __init__(self, store: Store, settings: StepSettings, enabled: bool = True) -> None:
        self.store = store
        self.settings = settings
        self.auto: Any = None
        self.enabled = enabled
        self._campaigns: dict[int, CampaignWatch] = {}
        #: Campaigns of hold checks: not watched (see :meth:`saw_sample`).
        self._check_campaigns: set[int] = set()
        #: Newest unacknowledged move per campaign (the page's banner): the event detail.
        self._moves: dict[int, dict[str, Any]] = {}

    def wrap(self, sink: CaptureSink) -> WatchedSink:
        """``sink`` with this watch listening to its stored captures."""
        return WatchedSink(sink, self)

    def start(self, auto: Any) -> None:
        """Follow ``auto`` (:class:`daemon.monitors.autocapture.AutoCapture` or None): a move
        found from now on takes auto capture to the new anchor."""
        self.auto = auto

    async def stop(self) -> None:
        """Cancel the campaigns' tasks."""
        for cw in self._campaigns.values():
            if cw.task is not None:
                cw.task.cancel()
                with contextlib.suppress(asyncio.CancelledError, Exception):
                    await cw.task

    async def idle(self) -> None:
        """Wait until every queued sample was tested (tests and benchmarks)."""
        while any(cw.task is not None and not cw.task.done() for cw in self._campaigns.values()):
            await asyncio.sleep(0.01)

    # ------------------------------------------------------------------ per sample
    def saw_sample(self, campaign_id: int, row: dict[str, Any]) -> None:
        """A sample was stored (called on the event loop, from the sink): queue it."""
        if not self.enabled:
            return
        if campaign_id in self._check_campaigns:
            return
        cw = self._campaigns.get(campaign_id)
        if cw is None:
            try:
                robot_id = int(self.store.campaign(campaign_id)["robot_id"])
                # A hold check's own campaign is never a sensor-move case of its own: its
                # few poses are compared with the calibration by the check, which says
                # whether the sensor or the robot moved (daemon.monitors.holdcheck).
                if self.store.check_of_campaign(campaign_id) is not None:
                    self._check_campaigns.add(campaign_id)
                    return
            except Exception:
                log.exception("watch: campaign %d unreadable", campaign_id)
                return
            nominal = self.store.robot_model(robot_id)
            calibration: Mapping[str, Any] | None = None
            with contextlib.suppress(Exception):  # none accepted yet
                calibration = self.store.accepted_result(robot_id)["result"]
            from calib.monitor.running_fit import LiveTester
            from calib.monitor.stepwatch import StepDetector

            tester = LiveTester(nominal, calibration, StepDetector(self.settings))
            cw = CampaignWatch(campaign_id, robot_id, tester)
            self._campaigns[campaign_id] = cw
            metrics.SENSOR_MOVED.labels(str(robot_id))  # the series exists at 0 (alerts)
        cw.queue.append(row)
        if cw.task is None or cw.task.done():
            cw.task = asyncio.get_running_loop().create_task(
                self._drain(cw), name=f"watch-{campaign_id}"
            )

    async def _drain(self, cw: CampaignWatch) -> None:
        while cw.queue:
            row = cw.queue.pop(0)
            try:
                await self._test(cw, row)
            except asyncio.CancelledError:
                raise
            except Exception:
                log.exception("watch: testing sample %s failed", row.get("id"))

    async def _test(self, cw: CampaignWatch, row: dict[str, Any]) -> None:
        sample_id = int(row["id"])
        current = self.store.get_sample(sample_id)
        if current is None or current["excluded"]:
            return
        if self._in_flight(cw, current):
            return
        samples, ids = self.store.sample_set(cw.campaign_id)
        tester = cw.tester
        clean = tester.clean_rows(ids, sample_id)
        if tester.needs_refit(len(clean)):
            await asyncio.to_thread(tester.refit_rows, samples, ids, clean)
        q = (
            current["q1"],
            current["q2"],
            current["q3"],
            current["q4"],
            current["q5"],
            current["q6"],
        )
        residual, alarm = tester.test(sample_id, q, current["length_mm"], str(current["anchor"]))
        if residual is not None:
            cw.tested += 1
            cw.last_residual_mm = residual
        if alarm is not None:
            self._moved(cw, alarm, ids)

    def _in_flight(self, cw: CampaignWatch, sample: Mapping[str, Any]) -> bool:
        """The first sample after a move, when it was captured in the old anchor session (in
        flight while auto capture switched), goes to the new session too (added to the
        banner's move; Undo takes back the new session's samples). Whether it was moved."""
        move = self._moves.get(cw.campaign_id)
        if not cw.after_move or move is None:
            return False
        sample_id = int(sample["id"])
        if str(sample["anchor"]) == move["new_anchor"]:
            cw.after_move = False  # captures go to the new session: nothing in flight
        if str(sample["anchor"]) != move["previous_anchor"] or sample_id <= int(
            move["detected_at_sample_id"]
        ):
            return False
        cw.after_move = False
        self.store.move_samples_to_anchor(cw.campaign_id, [sample_id], move["new_anchor"])
        move["moved_sample_ids"].append(sample_id)
        log.info(
            "watch: sample %d, in flight in anchor %s at the move, goes to %s",
            sample_id,
            move["previous_anchor"],
            move["new_anchor"],
        )
        return True

    # ------------------------------------------------------------------ a move
    def _moved(self, cw: CampaignWatch, alarm: StepAlarm, ids: list[int]) -> None:
        from calib.monitor.stepwatch import next_anchor

        cid = cw.campaign_id
        first = self.store.sample(int(alarm.first_key))
        previous = str(first["anchor"])
        campaign = self.store.campaign(cid)
        new = next_anchor(previous, campaign["anchors"])
        # Every sample of the old session from the step on: the alarm's, and any stored
        # since (still queued for the test).
        first_id = int(alarm.first_key)
        later = [
            int(r["id"])
            for r in self.store.list_samples(cid, after_id=first_id - 1)
            if r["anchor"] == previous
        ]
        moved = sorted({*(int(k) for k in alarm.keys), *later})
        self.store.move_samples_to_anchor(cid, moved, new)
        auto = self.auto is not None and self.auto.move_anchor(cid, new)
        row = ids.index(moved[0]) + 1 if moved[0] in ids else None
        fit = cw.tester.fit
        detail = {
            "campaign_id": cid,
            "robot_id": cw.robot_id,
            "sample_id": moved[0],
            "row": row,
            "detected_at_sample_id": max(int(k) for k in alarm.keys),
            "delay_samples": alarm.delay,
            "step_mm": round(alarm.step_mm, 4),
            "size_mm": round(alarm.size_mm, 4),
            "previous_anchor": previous,
            "new_anchor": new,
            "moved_sample_ids": moved,
            "auto_capture_switched": auto,
            "fit": fit.kind if fit else None,
            "fit_rmse_mm": round(fit.rmse_mm, 4) if fit else None,
        }
        message = (
            f"sensor moved at sample {moved[0]} (row {row}) of campaign {cid}: length change "
            f"{alarm.step_mm:+.2f} mm (median |change| {alarm.size_mm:.2f} mm); "
            f"{len(moved)} sample(s) and the next captures go to new anchor {new!r}"
        )
        self.store.record_event(SENSOR_MOVED, None, message, detail, campaign_id=cid)
        metrics.SENSOR_MOVED.labels(str(cw.robot_id)).inc()
        self._moves[cid] = detail
        cw.tester.moved()  # the new anchor has too few samples; refit from the next one
        cw.after_move = True
        log.warning(message, extra={"campaign_id": cid, "sample_id": moved[0]})

    def undo(self, campaign_id: int) -> dict[str, Any]:
        """Undo the newest automatic anchor split of a campaign: its new anchor's samples go
        back to the previous anchor, and so does auto capture when it uses the new one.

        Raises
        ------
        daemon.store.StoreNotFound
            No such campaign.
        NothingToUndo
            No ``sensor_moved`` event for the campaign, or it was undone already.
        """
        self.store.campaign(campaign_id)
        events = self.store.list_events(kind=SENSOR_MOVED, campaign_id=campaign_id, limit=1)
        if not events:
            raise NothingToUndo(f"campaign {campaign_id} has no sensor_moved event")
        event = events[-1]
        undone = self.store.list_events(kind=SENSOR_MOVED_UNDONE, campaign_id=campaign_id, limit=1)
        if undone and (undone[-1]["detail"] or {}).get("event_id") == event["id"]:
            raise NothingToUndo(f"sensor_moved event {event['id']} was undone already")
        detail = event["detail"] or {}
        new, previous = str(detail["new_anchor"]), str(detail["previous_anchor"])
        ids = [int(r["id"]) for r in self.store.list_samples(campaign_id) if r["anchor"] == new]
        self.store.move_samples_to_anchor(campaign_id, ids, previous)
        if self.auto is not None:
            self.auto.move_anchor(campaign_id, previous, from_anchor=new)
        out = {"event_id": event["id"], "anchor": previous, "from_anchor": new, "sample_ids": ids}
        self.store.record_event(
            SENSOR_MOVED_UNDONE,
            None,
            f"sensor move of campaign {campaign_id} undone by the operator: {len(ids)} "
            f"sample(s) back from anchor {new!r} to {previous!r}",
            out,
            campaign_id=campaign_id,
        )
        self._moves.pop(campaign_id, None)
        cw = self._campaigns.get(campaign_id)
        if cw is not None:
            cw.tester.detector.reset()
            cw.tester.moved()
        return out

    def offsets_mm(self, campaign_id: int) -> dict[str, float]:
        """The indicator's zero offset [mm] per anchor id in the campaign's running fit
        (empty without one): a plan keeps its predicted readings in range with it."""
        cw = self._campaigns.get(campaign_id)
        fit = None if cw is None else cw.tester.fit
        if fit is None:
            return {}
        from calib.cable import N_KIN

        return {
            aid: float(fit.theta[N_KIN + 4 * k + 3]) for k, aid in enumerate(fit.layout.anchors)
        }

    def status(self) -> dict[str, Any]:
        """The ``watch`` block of ``GET /status``: ``enabled``, ``moves`` (per campaign with
        an automatic split not undone since this start: the ``sensor_moved`` detail without
        the sample id list), ``campaigns`` (per watched campaign: ``fit``, ``fit_rmse_mm``,
        ``tested``, ``last_residual_mm``, ``band_mm``)."""
        moves = [
            {k: v for k, v in d.items() if k != "moved_sample_ids"} for d in self._moves.values()
        ]
        campaigns = []
        for cw in self._campaigns.values():
            fit = cw.tester.fit
            campaigns.append(
                {
                    "campaign_id": cw.campaign_id,
                    "fit": fit.kind if fit else None,
                    "fit_rmse_mm": None if fit is None else _round(fit.rmse_mm),
                    "tested": cw.tested,
                    "last_residual_mm": _round(cw.last_residual_mm),
                    "band_mm": _round(cw.tester.detector.band_mm),
                }
            )
        return {"enabled": self.enabled, "moves": moves, "campaigns": campaigns}


def _round(v: float | None) -> float | None:
    return None if v is None or not math.isfinite(v) else round(v, 4)
