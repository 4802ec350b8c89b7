"""The sampler's core: the poll loop, the capture path and the status of :class:`Sampler`.

The package docstring (:mod:`daemon.sampler`) describes the behaviour; auto mode's state and
decisions are in :mod:`daemon.sampler.auto`, the settings in :mod:`daemon.sampler.config`.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import time
from collections import deque
from collections.abc import Mapping, Sequence
from typing import Any, TypeVar

import numpy as np
from numpy.typing import NDArray

from daemon import metrics
from daemon.capture import CaptureRejected, CaptureSink, Joints
from daemon.devices import Device
from daemon.sampler.auto import AutoState, start_auto
from daemon.sampler.config import MAX_BUFFER, SamplerConfig
from daemon.settle import (
    NOT_SETTLED,
    Mode,
    PairedReading,
    Verdict,
    as_joints,
    evaluate,
    make_capture,
    staleness_s,
)
from drivers import (
    IndicatorDriver,
    IndicatorOverRange,
    ManualRobot,
    RobotDriver,
    RobotNoData,
    make_indicator,
    make_robot,
)
from drivers.indicator import IndicatorReading
from drivers.robot import JointReading

log = logging.getLogger("cablecal.sampler")

FloatArray = NDArray[np.float64]
_T = TypeVar("_T")


def _as_error(result: _T | BaseException) -> _T | Exception:
    """A driver's result, or its exception as an :class:`Exception`. Re-raises what must stop
    the loop (our own cancellation, KeyboardInterrupt, SystemExit); a driver that leaks a
    :class:`asyncio.CancelledError` of its own gets it reported as a failed poll."""
    if not isinstance(result, BaseException) or isinstance(result, Exception):
        return result
    task = asyncio.current_task()
    if isinstance(result, asyncio.CancelledError) and not (task and task.cancelling()):
        return RuntimeError(f"driver call was cancelled: {result!r}")
    raise result


# --------------------------------------------------------------------------- the sampler
class Sampler:
    """Polls ``indicator`` and ``robot``, detects settling, and hands captures to ``sink``.

    Parameters
    ----------
    indicator : IndicatorDriver
    robot : RobotDriver
        A :class:`drivers.ManualRobot` takes its joint angles from :meth:`capture`.
    config : SamplerConfig
    sink : CaptureSink
        Commits captures, rejections and device events (the store).

    Everything runs on one event loop: :meth:`start`, :meth:`capture`, :meth:`status` and
    :meth:`set_auto` must be called from the loop the sampler was started on.
    """

    def __init__(
        self,
        indicator: IndicatorDriver,
        robot: RobotDriver,
        config: SamplerConfig,
        sink: CaptureSink,
    ) -> None:
        self.indicator = indicator
        self.robot = robot
        self.config = config
        self.sink = sink
        self._ind = Device(indicator.name, "indicator", indicator, self._event)
        self._rob = Device(robot.name, "robot", robot, self._event)
        self._buffer: deque[PairedReading] = deque(maxlen=MAX_BUFFER)
        self._verdict: Verdict = NOT_SETTLED
        self._used_until = -math.inf  # t_poll of the newest reading used by a capture
        self._auto: AutoState | None = None
        self._task: asyncio.Task[None] | None = None
        self._tick = asyncio.Event()
        self._capture_lock = asyncio.Lock()

    # ------------------------------------------------------------------ lifecycle
    @property
    def running(self) -> bool:
        """True while the poll task runs."""
        return self._task is not None and not self._task.done()

    @property
    def manual_robot(self) -> bool:
        """True when the robot driver is a :class:`drivers.ManualRobot`."""
        return isinstance(self.robot, ManualRobot)

    @property
    def mode(self) -> Mode:
        """``auto`` while auto capture is enabled, else ``manual``."""
        return "manual" if self._auto is None else "auto"

    @property
    def auto_campaign_id(self) -> int | None:
        """The campaign auto mode captures into, or None."""
        return None if self._auto is None else self._auto.campaign_id

    async def start(self) -> None:
        """Launch the poll task on the running loop (no-op if it runs)."""
        if self.running:
            return
        self._tick = asyncio.Event()
        self._ind.t_started = self._rob.t_started = time.monotonic()
        self._event(
            "sampler_started",
            None,
            "sampler started",
            {"indicator": self._ind.name, "robot": self._rob.name, **self.config.model_dump()},
        )
        self._task = asyncio.get_running_loop().create_task(self._run(), name="cablecal-sampler")

    async def stop(self) -> None:
        """Cancel the poll task and close both drivers."""
        task, self._task = self._task, None
        if task is not None:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)
        for driver, dev in ((self.indicator, self._ind), (self.robot, self._rob)):
            try:
                await driver.close()
            except Exception:
                log.exception(
                    "closing %s %s failed", dev.role, dev.name, extra={"device": dev.name}
                )
        self._wake()

    # ------------------------------------------------------------------ poll loop
    async def _run(self) -> None:
        cfg = self.config
        while True:
            t_poll = time.monotonic()
            ind_res, rob_res = await asyncio.gather(
                self.indicator.read(), self.robot.read_joints(), return_exceptions=True
            )
            ind_res = _as_error(ind_res)
            rob_res = _as_error(rob_res)
            try:
                errored = self._cycle(t_poll, ind_res, rob_res)
            except Exception:  # a bug in a cycle must not stop sampling
                log.exception("sampler cycle failed")
                errored = True
            self._wake()
            if errored:
                delay = cfg.error_backoff_s
            else:
                delay = max(0.0, cfg.poll_interval_s - (time.monotonic() - t_poll))
            await asyncio.sleep(delay)

    def _wake(self) -> None:
        """Wake every :meth:`capture` waiting for the next cycle."""
        self._tick.set()
        self._tick = asyncio.Event()

    def _cycle(
        self,
        t_poll: float,
        ind_res: IndicatorReading | Exception,
        rob_res: JointReading | Exception,
    ) -> bool:
        """Book one poll of both devices; returns True when a device failed."""
        t_done, w_done = time.monotonic(), time.time()
        errored = False
        ind, rob = self._ind, self._rob
        ind.prune(t_done)
        rob.prune(t_done)

        length: float | None = None
        over = False
        t_ind, w_ind = t_done, w_done
        if isinstance(ind_res, IndicatorOverRange):
            # The meter answered; its value is not a length. Counted, not an error episode.
            ind.count_error(ind_res)
            ind.good(t_poll, None, True, t_done, w_done, count_poll=False)
            length, over = math.nan, True
        elif isinstance(ind_res, Exception):
            ind.failed(t_poll, ind_res)
            errored = True
        else:
            length, over = ind_res.length_mm, ind_res.over_range
            t_ind, w_ind = ind_res.t_monotonic_s, ind_res.t_wall
            ind.good(t_poll, length, over, t_ind, w_ind)

        joints: Joints | None = None
        t_rob = t_done
        if isinstance(rob_res, RobotNoData):
            rob.waiting(t_poll, rob_res)
        elif isinstance(rob_res, Exception):
            rob.failed(t_poll, rob_res)
            errored = True
        else:
            joints, t_rob = rob_res.joints_deg, rob_res.t_monotonic_s
            rob.good(t_poll, joints, False, t_rob, rob_res.t_wall)
            if self._auto is not None:
                self._auto.saw_joints(joints, self.config.settle_tol_deg)

        if length is not None and joints is not None:
            staleness = staleness_s(t_done, t_ind, t_rob, self.manual_robot)
            self._append(PairedReading(t_poll, t_ind, w_ind, joints, length, over, staleness))
        self._verdict = self._evaluate(t_done, -math.inf)
        if self._auto is not None and not self._capture_lock.locked():
            self._auto_step(t_done)
        return errored

    def _append(self, reading: PairedReading) -> None:
        buf = self._buffer
        buf.append(reading)
        horizon = reading.t_mono - self.config.history_s
        while buf and buf[0].t_mono < horizon:
            buf.popleft()

    def _event(
        self, kind: str, device: str | None, message: str, detail: dict[str, Any] | None
    ) -> None:
        try:
            self.sink.record_event(kind, device, message, detail)
        except Exception:
            log.exception("recording event %s failed", kind, extra={"device": device})

    # ------------------------------------------------------------------ settle detection
    def _evaluate(self, now: float, not_before: float) -> Verdict:
        """Settle check of the window ending at the newest reading polled at or after
        ``not_before`` (monotonic [s]); see :func:`daemon.settle.evaluate`."""
        return evaluate(self._buffer, self.config, now, not_before, self._ind.name)

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
        anchor: str = "A",
        joints_deg: Sequence[float] | None = None,
        mode: Mode = "manual",
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
            t_request = time.monotonic()
            if joints is not None:
                assert isinstance(self.robot, ManualRobot)
                self.robot.submit(joints)
            try:
                window = await self._wait_settled(t_request)
            except CaptureRejected as exc:
                self._rejected(campaign_id, exc, mode)
                raise
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
                raise CaptureRejected(verdict.reason, verdict.detail)
            if not self.running:
                raise CaptureRejected("no_data", "the sampler is not running")
            if now >= deadline:
                raise CaptureRejected(
                    verdict.reason,
                    f"not settled within capture_timeout_s {cfg.capture_timeout_s} s: "
                    f"{verdict.detail}",
                )
            tick = self._tick
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(tick.wait(), min(deadline - now, cfg.stale_s) + 1e-3)

    def _rejected(self, campaign_id: int | None, exc: CaptureRejected, mode: Mode) -> None:
        metrics.CAPTURES.labels("rejected", exc.reason, mode).inc()
        log.info(
            "capture rejected: %s",
            exc,
            extra={"campaign_id": campaign_id, "device": exc.device, "error": exc.reason},
        )
        try:
            self.sink.record_rejection(campaign_id, exc.reason, exc.detail, exc.device)
        except Exception:
            log.exception("recording a rejection failed", extra={"campaign_id": campaign_id})

    def _store(
        self, campaign_id: int, anchor: str, window: tuple[PairedReading, ...], mode: Mode
    ) -> dict[str, Any]:
        capture = make_capture(window, anchor, mode)
        row = dict(self.sink.store_capture(campaign_id, capture))  # commits before returning
        self._used_until = window[-1].t_poll
        metrics.CAPTURES.labels("accepted", "ok", mode).inc()
        auto = self._auto
        if auto is not None and auto.campaign_id == campaign_id:
            auto.captured(np.array(capture.joints_deg))
        log.info(
            "captured %s sample: length %.3f mm, %d readings",
            mode,
            capture.length_mm,
            capture.count,
            extra={"campaign_id": campaign_id, "sample_id": row.get("id")},
        )
        return row

    # ------------------------------------------------------------------ auto mode
    def set_auto(
        self,
        campaign_id: int | None,
        anchor: str = "A",
        known_poses_deg: FloatArray | Sequence[Sequence[float]] | None = None,
    ) -> None:
        """Enable auto capture into ``campaign_id`` (None disables).

        Parameters
        ----------
        campaign_id : int or None
        anchor : str
        known_poses_deg : array_like, shape (n, 6), optional
            Poses [deg] captured in the campaign already (e.g. before a daemon restart);
            they are not captured again. Re-enabling the same campaign keeps the poses
            captured since it was first enabled.

        Raises
        ------
        ValueError
            ``known_poses_deg`` not of shape (n, 6).
        """
        if campaign_id is None:
            self._auto = None
            return
        self._auto = start_auto(
            campaign_id, anchor, known_poses_deg, self._auto, now=time.monotonic()
        )

    @property
    def auto_anchor(self) -> str | None:
        """The anchor auto mode captures with, or None."""
        return None if self._auto is None else self._auto.anchor

    def set_auto_anchor(self, anchor: str) -> None:
        """Go on capturing in auto mode with another anchor id (the sensor moved); the poses
        known stay known. No-op without auto mode."""
        if self._auto is not None:
            self._auto.anchor = anchor

    def _auto_step(self, now: float) -> None:
        """Take auto mode's decision for this cycle (:meth:`AutoState.decide`)."""
        auto = self._auto
        assert auto is not None
        verdict = self._evaluate(now, max(auto.since, self._used_until + 1e-9))
        fault = self._device_fault(now, auto.since)
        last = self._buffer[-1].joints_deg if self._buffer else None
        action = auto.decide(verdict, fault, now, self.config, last)
        if action.reject is not None:
            self._rejected(auto.campaign_id, action.reject, "auto")
        elif action.store:
            try:
                self._store(auto.campaign_id, auto.anchor, verdict.window, "auto")
            except Exception as exc:
                log.exception(
                    "storing an auto capture failed", extra={"campaign_id": auto.campaign_id}
                )
                auto.store_failed(now, self.config)
                # Counted and logged as an event, so a store that refuses every capture is
                # visible in /metrics and /events, not only in the log.
                metrics.CAPTURES.labels("failed", "store_error", "auto").inc()
                self._event(
                    "capture_failed",
                    None,
                    f"store_error: {type(exc).__name__}: {exc}",
                    {"campaign_id": auto.campaign_id, "error": f"{type(exc).__name__}: {exc}"},
                )

    # ------------------------------------------------------------------ status
    def status(self) -> dict[str, Any]:
        """Devices and sampler state; cheap (no I/O, nothing proportional to the buffer).

        Returns
        -------
        dict
            ``devices``: ``{"indicator": {...}, "robot": {...}}``, each with ``name``,
            ``role``, ``driver`` (class), ``state`` (``ok``, ``error`` or ``unknown``),
            ``connected``, ``waiting_for`` (manual robot without angles), ``last_reading``
            (``value`` [mm] or joint list [deg], ``over_range``, ``age_s``, ``t_wall``) or
            None, ``last_error`` (``class``, ``message``, ``frames_hex``, ``age_s``,
            ``t_wall``) or None, ``poll_rate_hz``, ``polls``, ``errors``, ``errors_by_class``.
            ``sampler``: ``running``, ``mode``, ``auto_campaign_id``, ``auto_anchor``,
            ``auto_known_poses``, ``settled``, ``settle_state`` (``settled`` or the reason it
            is not), ``settle_detail``, ``readings_in_buffer``.
        """
        now = time.monotonic()
        verdict = self._verdict
        latest = self._buffer[-1] if self._buffer else None
        settled = (
            verdict.reason is None
            and latest is not None
            and now - latest.t_mono <= self.config.stale_s
        )
        auto = self._auto
        return {
            "devices": {"indicator": self._ind.status(now), "robot": self._rob.status(now)},
            "sampler": {
                "running": self.running,
                "mode": self.mode,
                "auto_campaign_id": None if auto is None else auto.campaign_id,
                "auto_anchor": None if auto is None else auto.anchor,
                "auto_known_poses": 0 if auto is None else int(auto.known.shape[0]),
                "settled": settled,
                "settle_state": "settled" if settled else verdict.reason,
                "settle_detail": verdict.detail,
                "readings_in_buffer": len(self._buffer),
            },
        }

    def recent_readings(self, since_wall_s: float, limit: int) -> list[PairedReading]:
        """The paired readings of the ring buffer (the last ``history_s``) whose length
        stamp ``t_wall`` is later than ``since_wall_s`` [s, Unix time], oldest first, at
        most the newest ``limit`` of them (the operator page's live trace)."""
        out: list[PairedReading] = []
        for reading in reversed(self._buffer):
            if reading.t_wall <= since_wall_s or len(out) >= limit:
                break
            out.append(reading)
        out.reverse()
        return out

    def update_age_metrics(self) -> None:
        """Set :data:`metrics.LAST_READING_AGE` of both devices (NaN before any reading)."""
        now = time.monotonic()
        for dev in (self._ind, self._rob):
            age = math.nan if dev.t_mono is None else now - dev.t_mono
            metrics.LAST_READING_AGE.labels(dev.name, dev.role).set(age)


def build_sampler(
    indicator_cfg: Mapping[str, Any],
    robot_cfg: Mapping[str, Any],
    config: SamplerConfig | Mapping[str, Any] | None,
    sink: CaptureSink,
) -> Sampler:
    """A :class:`Sampler` with drivers from :func:`drivers.make_indicator` and
    :func:`drivers.make_robot`. Raises ``pydantic.ValidationError`` / ``ValueError`` on bad
    settings."""
    if config is None:
        cfg = SamplerConfig()
    elif isinstance(config, SamplerConfig):
        cfg = config
    else:
        cfg = SamplerConfig.model_validate(dict(config))
    return Sampler(make_indicator(indicator_cfg), make_robot(robot_cfg), cfg, sink)
