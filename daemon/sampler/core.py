"""The sampler's core: the poll loop, the capture path and the status of :class:`Sampler`.

The package docstring (:mod:`daemon.sampler`) describes the behaviour; auto mode's state and
decisions are in :mod:`daemon.sampler.auto`, the settings in :mod:`daemon.sampler.config`.
"""

from __future__ import annotations

import asyncio
import logging
import math
import time
from collections import deque
from collections.abc import Awaitable, Iterable, Mapping, Sequence
from typing import Any, TypeVar

from calib.sample_fields import DEFAULT_ANCHOR, Joints
from daemon import metrics
from daemon.sampler.auto import AutoState, start_auto
from daemon.sampler.cancel import raise_if_cancelled
from daemon.sampler.capture import CaptureMode, CaptureSink
from daemon.sampler.captures import CapturePath
from daemon.sampler.config import MAX_BUFFER, SamplerConfig
from daemon.sampler.devices import Device
from daemon.sampler.late import LateWatch
from daemon.sampler.settle import (
    NOT_SETTLED,
    FrozenWatch,
    PairedReading,
    Verdict,
    staleness_s,
)
from drivers import (
    IndicatorDriver,
    IndicatorOverRange,
    RobotDriver,
    RobotNoData,
    make_indicator,
    make_robot,
)
from drivers.indicator import IndicatorReading
from drivers.robot import JointReading

log = logging.getLogger("cablecal.sampler")

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


async def _outcome(call: Awaitable[_T]) -> _T | Exception:
    """The result of a driver call, or its exception (see :func:`_as_error`)."""
    try:
        return await call
    except BaseException as exc:
        return _as_error(exc)


# --------------------------------------------------------------------------- the sampler
class Sampler(CapturePath):
    """Polls ``indicator`` and ``robot``, detects settling, and hands captures to ``sink``
    (the capture path: :class:`daemon.sampler.captures.CapturePath`).

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
        self._late = LateWatch(self._rob, self._event)
        #: The robot's newest joints [deg], their stamp and the start of their poll
        #: (monotonic [s]); None while the robot fails or has no data.
        self._joints: tuple[Joints, float, float] | None = None
        self._buffer: deque[PairedReading] = deque(maxlen=MAX_BUFFER)
        self._verdict: Verdict = NOT_SETTLED
        self._frozen = FrozenWatch(config.settle_tol_mm, config.min_readings, config.settle_s)
        self._used_until = -math.inf  # t_poll of the newest reading used by a capture
        self._auto: AutoState | None = None
        self._task: asyncio.Task[None] | None = None
        self._tick = asyncio.Event()
        self._capture_lock = asyncio.Lock()
        #: The campaign of the manual capture holding the lock, or None.
        self._manual_campaign_id: int | None = None

    # ------------------------------------------------------------------ lifecycle
    @property
    def mode(self) -> CaptureMode:
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

    # ------------------------------------------------------------------ poll loops
    async def _run(self) -> None:
        """The indicator's loop, which pairs each length with the robot's newest joints. The
        robot has a loop of its own, so a slow device never slows the other; the manual
        robot (no I/O: the angles typed in) is read in this loop."""
        robot_task = None
        if not self.manual_robot:
            robot_task = asyncio.get_running_loop().create_task(
                self._run_robot(), name="cablecal-sampler-robot"
            )
        try:
            await self._run_indicator()
        finally:
            if robot_task is not None:
                robot_task.cancel()
                await asyncio.gather(robot_task, return_exceptions=True)

    async def _run_indicator(self) -> None:
        while True:
            raise_if_cancelled()
            t_poll = time.monotonic()
            if self.manual_robot:
                ind_res, rob_res = await asyncio.gather(
                    self.indicator.read(), self.robot.read_joints(), return_exceptions=True
                )
                self._book_robot(t_poll, _as_error(rob_res))
                ind_res = _as_error(ind_res)
            else:
                ind_res = await _outcome(self.indicator.read())
            try:
                errored = self._cycle(t_poll, ind_res)
            except Exception:  # a bug in a cycle must not stop sampling
                log.exception("sampler cycle failed")
                errored = True
            self._wake()
            await asyncio.sleep(self._delay(t_poll, errored))

    async def _run_robot(self) -> None:
        """The robot's loop: one poll per indicator cycle (a faster robot would only be polled
        for nothing), but never waiting longer than :meth:`_robot_wait_s` for that cycle."""
        while True:
            raise_if_cancelled()
            t_poll = time.monotonic()
            tick = self._tick
            result = await _outcome(self.robot.read_joints())
            try:
                errored = self._book_robot(t_poll, result)
            except Exception:  # a bug in the book-keeping must not stop polling
                log.exception("robot poll book-keeping failed")
                errored = True
            delay = self._delay(t_poll, errored)
            if delay > 0 or errored:
                await asyncio.sleep(delay)
            else:
                # asyncio.wait, not wait_for: Python 3.11's wait_for can swallow a cancel that
                # arrives as the tick fires, and stop() would then wait for this loop forever.
                waiter = asyncio.ensure_future(tick.wait())
                try:
                    await asyncio.wait({waiter}, timeout=self._robot_wait_s())
                finally:
                    waiter.cancel()

    def _robot_wait_s(self) -> float:
        """Longest wait of the robot's loop for an indicator cycle [s]: a settle window then
        still holds twice ``min_readings`` robot readings while the indicator is slow."""
        return self.config.settle_s / (2 * self.config.min_readings)

    def _delay(self, t_poll: float, errored: bool) -> float:
        """Pause before a device's next poll [s]: the back-off after an error, else the rest
        of ``poll_interval_s``."""
        if errored:
            return self.config.error_backoff_s
        return max(0.0, self.config.poll_interval_s - (time.monotonic() - t_poll))

    def _wake(self) -> None:
        """Wake every :meth:`capture` waiting for the next cycle."""
        self._tick.set()
        self._tick = asyncio.Event()

    def _book_robot(self, t_poll: float, result: JointReading | Exception) -> bool:
        """Book one robot poll (started at ``t_poll``); returns True when it failed."""
        rob = self._rob
        rob.prune(time.monotonic())
        if isinstance(result, RobotNoData):
            rob.waiting(t_poll, result)
            self._joints = None
            return False
        if isinstance(result, Exception):
            rob.failed(t_poll, result)
            self._joints = None
            return True
        joints, t_rob = result.joints_deg, result.t_monotonic_s
        rob.good(t_poll, joints, False, t_rob, result.t_wall)
        self._joints = (joints, t_rob, t_poll)
        self._late.on_reading(time.monotonic())
        if self._auto is not None:
            self._auto.saw_joints(joints, self.config.settle_tol_deg)
        return False

    def _cycle(self, t_poll: float, ind_res: IndicatorReading | Exception) -> bool:
        """Book one indicator poll, pair it with the robot's newest joints and take the
        cycle's decisions; returns True when the indicator failed."""
        t_done, w_done = time.monotonic(), time.time()
        errored = False
        ind = self._ind
        ind.prune(t_done)

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

        paired = self._joints
        if length is not None and paired is not None:
            joints, t_rob, t_poll_rob = paired
            staleness = staleness_s(t_done, t_ind, t_rob, self.manual_robot)
            # Polled when the older of the two polls started: a capture requested after it
            # takes neither reading (not_before), and no reading goes into two captures.
            t_pair = min(t_poll, t_poll_rob)
            t_joints = math.nan if self.manual_robot else t_rob
            self._append(
                PairedReading(t_pair, t_ind, w_ind, joints, length, over, staleness, t_joints)
            )
        late = not self.manual_robot and self._late.check(t_done, self.config.settle_s)
        self._verdict = self._evaluate(t_done, -math.inf)
        # Auto capture steps every cycle, also while a manual capture into another campaign
        # waits (a loop of manual captures would starve it otherwise); the window it takes is
        # marked used, so the manual capture takes the next one. While a manual capture into
        # the auto campaign itself waits, auto steps aside (no pose captured twice there).
        if self._auto is not None and not (
            self._capture_lock.locked() and self._manual_campaign_id == self._auto.campaign_id
        ):
            self._auto_step(t_done, late)
        return errored

    def _append(self, reading: PairedReading) -> None:
        buf = self._buffer
        buf.append(reading)
        horizon = reading.t_mono - self.config.history_s
        while buf and buf[0].t_mono < horizon:
            buf.popleft()
        self._frozen.add(reading, buf[0])

    def _event(
        self, kind: str, device: str | None, message: str, detail: dict[str, Any] | None
    ) -> None:
        try:
            self.sink.record_event(kind, device, message, detail)
        except Exception:
            log.exception("recording event %s failed", kind, extra={"device": device})

    # ------------------------------------------------------------------ auto mode
    def set_auto(
        self,
        campaign_id: int | None,
        anchor: str = DEFAULT_ANCHOR,
        known_poses_deg: Iterable[Sequence[float]] | None = None,
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

    def _auto_step(self, now: float, robot_late: bool) -> None:
        """Take auto mode's decision for this cycle (:meth:`AutoState.decide`)."""
        auto = self._auto
        assert auto is not None
        verdict = self._evaluate(now, max(auto.since, self._used_until + 1e-9))
        fault = self._device_fault(now, auto.since)
        last = self._buffer[-1].joints_deg if self._buffer else None
        action = auto.decide(verdict, fault, now, self.config, last, robot_late)
        if action.lost is not None:
            self._lost(auto.campaign_id, action.lost, last)
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

    def _lost(self, campaign_id: int, reason: str, joints_deg: Joints | None) -> None:
        """Count and record a pose the robot left without a capture (auto mode)."""
        metrics.POSES_LOST.labels(reason).inc()
        message = f"auto capture: the robot left a still pose without a capture ({reason})"
        log.warning(message, extra={"campaign_id": campaign_id, "error": reason})
        detail = {"campaign_id": campaign_id, "reason": reason, "joints_deg": joints_deg}
        self._event("pose_lost", self._rob.name, message, detail)

    # ------------------------------------------------------------------ status
    def status(self) -> dict[str, Any]:
        """Devices and sampler state; cheap (no I/O, nothing proportional to the buffer).

        Returns
        -------
        dict
            ``devices``: ``{"indicator": {...}, "robot": {...}}``, each with ``name``,
            ``role``, ``driver`` (class), ``state`` (``ok``, ``error``, ``unknown``, or for the
            robot ``late``: it answers, but its newest joints are older than ``settle_s``;
            :mod:`daemon.sampler.late`), the robot's ``late``, ``late_age_s`` [s] and
            ``late_episodes``,
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
        robot = self._rob.status(now) | self._late.status(now)
        if robot["late"]:
            robot["state"] = "late"
        return {
            "devices": {"indicator": self._ind.status(now), "robot": robot},
            "sampler": {
                "running": self.running,
                "mode": self.mode,
                "auto_campaign_id": None if auto is None else auto.campaign_id,
                "auto_anchor": None if auto is None else auto.anchor,
                "auto_known_poses": 0 if auto is None else len(auto.known),
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
