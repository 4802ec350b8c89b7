"""The sampler's capture path: settle checks, device faults, manual captures, rejections and
stores (a mixin of :class:`daemon.sampler.core.Sampler`, whose attributes it names below)."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import time
from collections import deque
from collections.abc import Sequence
from typing import Any

from calib.sample_fields import DEFAULT_ANCHOR, Joints
from daemon import metrics
from daemon.sampler.auto import AutoState
from daemon.sampler.cancel import raise_if_cancelled
from daemon.sampler.capture import CaptureMode, CaptureRejected, CaptureSink
from daemon.sampler.config import SamplerConfig
from daemon.sampler.devices import Device
from daemon.sampler.settle import (
    FrozenWatch,
    PairedReading,
    Verdict,
    as_joints,
    evaluate,
    make_capture,
)
from drivers import ManualRobot, RobotDriver

log = logging.getLogger("cablecal.sampler")


class CapturePath:
    """Settle checks and captures over the sampler's buffer (see the module)."""

    robot: RobotDriver
    config: SamplerConfig
    sink: CaptureSink
    _ind: Device
    _rob: Device
    _buffer: deque[PairedReading]
    _frozen: FrozenWatch
    _used_until: float
    _joints: tuple[Joints, float, float] | None
    _auto: AutoState | None
    _task: asyncio.Task[None] | None
    _tick: asyncio.Event
    _capture_lock: asyncio.Lock
    _manual_campaign_id: int | None

    @property
    def running(self) -> bool:
        """True while the poll task runs."""
        return self._task is not None and not self._task.done()

    @property
    def manual_robot(self) -> bool:
        """True when the robot driver is a :class:`drivers.ManualRobot`."""
        return isinstance(self.robot, ManualRobot)

    # ------------------------------------------------------------------ settle detection
    def _evaluate(self, now: float, not_before: float) -> Verdict:
        """Settle check of the window ending at the newest reading polled at or after
        ``not_before`` (monotonic [s]); see :func:`daemon.sampler.settle.evaluate`. A frozen
        controller (:class:`daemon.sampler.settle.FrozenWatch`) outranks a settled or over-range
        window: its joints are not the robot's (a moving one stays ``moving``: it is not
        ready either, and a noisy cable at rest is not a frozen controller)."""
        verdict = evaluate(self._buffer, self.config, now, not_before, self._ind.name)
        if verdict.reason in (None, "over_range"):
            frozen = self._frozen.verdict(self._buffer[-1] if self._buffer else None)
            if frozen is not None:
                return frozen
        return verdict

    def _device_fault(self, now: float, not_before: float) -> tuple[CaptureRejected, Device] | None:
        """A device failing for longer than ``stale_s``, or the manual robot without angles
        (seen in a poll after ``not_before``)."""
        for dev in (self._ind, self._rob):
            rejection = dev.fault(now, self.config.stale_s)
            if rejection is not None:
                return rejection, dev
        rob = self._rob
        if rob.no_data is not None and rob.t_state_poll >= not_before:
            hint = "; send joints_deg with the capture" if self.manual_robot else ""
            detail = f"robot {rob.name}: {rob.no_data}{hint}"
            return CaptureRejected("no_data", detail, device=rob.name), rob
        return None

    # ------------------------------------------------------------------ captures
    async def capture(
        self,
        campaign_id: int,
        anchor: str = DEFAULT_ANCHOR,
        joints_deg: Sequence[float] | None = None,
        mode: CaptureMode = "manual",
    ) -> dict[str, Any]:
        """Capture the next settled window after this call; returns the stored sample row.

        Parameters
        ----------
        campaign_id : int
        anchor : str
            Sensor position id.
        joints_deg : sequence of 6 float, optional
            Joint angles [deg] for the manual robot driver; submitted before waiting.
        mode : {"manual", "auto"}
            Label of the capture (metrics, stored sample).

        Raises
        ------
        ValueError
            ``joints_deg`` given for a driver other than the manual one, or not 6 finite
            numbers.
        CaptureRejected
            No settled window within ``capture_timeout_s`` (``moving``, ``stale``,
            ``over_range``, ``no_data``), or a device is failing (``indicator_error``,
            ``robot_error``). The rejection is recorded and counted first.
        """
        joints: Joints | None = None
        if joints_deg is not None:
            if not isinstance(self.robot, ManualRobot):
                raise ValueError(
                    f"joints_deg: robot {self.robot.name} ({type(self.robot).__name__}) reports "
                    "its own joint angles; only the manual driver takes them from the request"
                )
            values = [float(v) for v in joints_deg]
            if len(values) != 6 or not all(math.isfinite(v) for v in values):
                raise ValueError(f"joints_deg: expected 6 finite angles [deg], got {values}")
            joints = as_joints(values)
        async with self._capture_lock:
            self._manual_campaign_id = campaign_id
            t_request = time.monotonic()
            if joints is not None:
                assert isinstance(self.robot, ManualRobot)
                self.robot.submit(joints)
            try:
                window = await self._wait_settled(t_request)
            except CaptureRejected as exc:
                self._rejected(campaign_id, exc, mode)
                raise
            finally:
                self._manual_campaign_id = None
            raise_if_cancelled()  # a capture whose request was cancelled stores nothing
            return self._store(campaign_id, anchor, window, mode)

    async def _wait_settled(self, t_request: float) -> tuple[PairedReading, ...]:
        cfg = self.config
        deadline = t_request + cfg.capture_timeout_s
        while True:
            now = time.monotonic()
            not_before = max(t_request, self._used_until + 1e-9)
            fault = self._device_fault(now, not_before)
            if fault is not None:
                raise fault[0]
            verdict = self._evaluate(now, not_before)
            if verdict.reason is None:
                return verdict.window
            if verdict.final:
                device = self._rob.name if verdict.reason == "frozen" else None
                raise CaptureRejected(verdict.reason, verdict.detail, device=device)
            if not self.running:
                raise CaptureRejected("no_data", "the sampler is not running")
            if now >= deadline:
                raise CaptureRejected(
                    verdict.reason,
                    f"not settled within capture_timeout_s {cfg.capture_timeout_s} s: "
                    f"{verdict.detail}",
                )
            tick = self._tick
            # asyncio.timeout, not wait_for: Python 3.11's wait_for returns normally when a
            # cancel arrives as the tick fires, and the cancelled capture would go on to store.
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(min(deadline - now, cfg.stale_s) + 1e-3):
                    await tick.wait()

    def _rejected(self, campaign_id: int | None, exc: CaptureRejected, mode: CaptureMode) -> None:
        metrics.CAPTURES.labels("rejected", exc.reason, mode).inc()
        log.info(
            "capture rejected: %s",
            exc,
            extra={"campaign_id": campaign_id, "device": exc.device, "error": exc.reason},
        )
        joints = None if self._joints is None else self._joints[0]  # the pose, when known
        try:
            self.sink.record_rejection(
                campaign_id, exc.reason, exc.detail, exc.device, joints_deg=joints
            )
        except Exception:
            log.exception("recording a rejection failed", extra={"campaign_id": campaign_id})

    def _store(
        self, campaign_id: int, anchor: str, window: tuple[PairedReading, ...], mode: CaptureMode
    ) -> dict[str, Any]:
        capture = make_capture(window, anchor, mode)
        row = dict(self.sink.store_capture(campaign_id, capture))  # commits before returning
        self._used_until = window[-1].t_poll
        metrics.CAPTURES.labels("accepted", "ok", mode).inc()
        auto = self._auto
        if auto is not None and auto.campaign_id == campaign_id:
            auto.captured(capture.joints_deg)
        log.info(
            "captured %s sample: length %.3f mm, %d readings",
            mode,
            capture.length_mm,
            capture.count,
            extra={"campaign_id": campaign_id, "sample_id": row.get("id")},
        )
        return row
