"""What the sampler knows about each device: state, last reading and error, counts, events.

One :class:`Device` per polled device (the indicator and the robot). The poll loop books each
poll's outcome with :meth:`Device.good`, :meth:`Device.failed`, :meth:`Device.count_error` or
:meth:`Device.waiting`; these update the state, the Prometheus metrics and the log, and report
device events (``link_down``, ``device_error`` at the start of an error episode, ``link_up``
when the device delivers again) through the ``on_event`` callback. :meth:`Device.status` is the
device's part of ``GET /status``.
"""

from __future__ import annotations

import logging
import math
import time
from collections import deque
from collections.abc import Callable
from typing import Any, Literal

from calib.sample_fields import Joints
from daemon import metrics
from daemon.sampler.capture import CaptureRejected, RejectionReason
from drivers import DeviceError, DeviceLinkDown, RobotNoData

# The device book-keeping is part of the sampler: its records keep the sampler's logger name.
log = logging.getLogger("cablecal.sampler")

Role = Literal["indicator", "robot"]
#: ``on_event(kind, device, message, detail)``: record a device event (never raises).
EventCallback = Callable[[str, str | None, str, dict[str, Any] | None], None]

#: Poll rates in :meth:`Device.status` are averaged over this span [s].
RATE_WINDOW_S = 5.0


class Device:
    """What the sampler knows about one device (for status, events and metrics).

    Parameters
    ----------
    name : str
        The driver's name (metric and event label).
    role : {"indicator", "robot"}
    driver : object
        The driver; its class name is reported as ``driver`` in the status.
    on_event : EventCallback
        Records device events.
    """

    def __init__(self, name: str, role: Role, driver: object, on_event: EventCallback) -> None:
        self.name = name
        self.role: Role = role
        self.kind = type(driver).__name__
        #: The maker whose controller the driver reads (its ``MAKER``), None when it does not say.
        self.maker: str | None = getattr(driver, "MAKER", None)
        self.on_event = on_event
        self.state: Literal["unknown", "ok", "error"] = "unknown"
        self.no_data: str | None = None  # RobotNoData message (manual robot waiting)
        self.t_state_poll = -math.inf  # t_poll of the poll that set the state
        self.value: float | Joints | None = None
        self.over_range = False
        self.t_mono: float | None = None  # stamp of the last reading (or over-range reply)
        self.t_wall: float | None = None
        self.last_good_mono: float | None = None
        self.error: DeviceError | Exception | None = None
        self.error_wall: float | None = None
        self.error_mono: float | None = None
        self.episode_start_mono: float | None = None
        self.errors: dict[str, int] = {}
        self.polls = 0
        self.episode = 0  # increments at the start of each error / no-data episode
        self.stamps: deque[float] = deque()  # good readings in the last RATE_WINDOW_S
        self.t_started = time.monotonic()
        self.polls_counter = metrics.DEVICE_POLLS.labels(name, role)

    # ------------------------------------------------------------------ book-keeping
    def good(
        self,
        t_poll: float,
        value: float | Joints | None,
        over_range: bool,
        t_mono: float,
        t_wall: float,
        count_poll: bool = True,
    ) -> None:
        """The device answered (``value`` None: an over-range reply without a value); after an
        error episode this is a reconnect (``link_up`` event)."""
        if self.state == "error":
            metrics.DEVICE_RECONNECTS.labels(self.name, self.role).inc()
            start = self.episode_start_mono
            down_s = time.monotonic() - start if start is not None else 0.0
            message = f"{self.role} {self.name} delivers again after {down_s:.2f} s"
            log.info(message, extra={"device": self.name})
            self.on_event("link_up", self.name, message, {"last_error": self.error_text()})
        self.state, self.no_data, self.t_state_poll = "ok", None, t_poll
        self.value, self.over_range = value, over_range
        self.t_mono, self.t_wall = t_mono, t_wall
        self.last_good_mono = t_mono
        self.stamps.append(t_mono)
        if count_poll:
            self.polls += 1
            self.polls_counter.inc()

    def count_error(self, exc: Exception) -> None:
        """Count a failed poll by error class (no state change)."""
        cls = type(exc).__name__
        self.errors[cls] = self.errors.get(cls, 0) + 1
        metrics.DEVICE_ERRORS.labels(self.name, self.role, cls).inc()

    def failed(self, t_poll: float, exc: Exception) -> None:
        """The poll raised ``exc``: count and log it; the first failure of an episode records a
        ``link_down`` or ``device_error`` event with the last frames."""
        cls = type(exc).__name__
        self.count_error(exc)
        previous = type(self.error).__name__ if self.state == "error" else None
        first = self.state != "error"
        self.state, self.t_state_poll = "error", t_poll
        self.error, self.error_wall, self.error_mono = exc, time.time(), time.monotonic()
        frames = self.frames()
        extra = {"device": self.name, "frames_hex": frames, "error": cls}
        text = self.error_text()
        if not isinstance(exc, DeviceError):  # a driver bug: keep the traceback
            log.error(
                "%s %s poll failed: %s", self.role, self.name, text, exc_info=exc, extra=extra
            )
        elif first or cls != previous:
            log.warning("%s %s poll failed: %s", self.role, self.name, text, extra=extra)
        else:
            log.debug("%s %s poll failed: %s", self.role, self.name, text, extra=extra)
        if first:
            self.episode += 1
            self.episode_start_mono = self.error_mono
            kind = "link_down" if isinstance(exc, DeviceLinkDown) else "device_error"
            self.on_event(kind, self.name, text, {"error": cls, "frames_hex": frames})

    def waiting(self, t_poll: float, exc: RobotNoData) -> None:
        """Manual robot without (fresh) angles: no data, not a fault."""
        if self.no_data is None:
            self.episode += 1
        self.state, self.no_data, self.t_state_poll = "unknown", exc.message, t_poll

    def fault(self, now: float, stale_s: float) -> CaptureRejected | None:
        """The rejection of a device in error with no good reading for over ``stale_s``."""
        if self.state != "error":
            return None
        if self.last_good_mono is not None and now - self.last_good_mono <= stale_s:
            return None
        reason: RejectionReason = "indicator_error" if self.role == "indicator" else "robot_error"
        detail = f"{self.role} {self.name}: {self.error_text()}"
        return CaptureRejected(reason, detail, device=self.name)

    # ------------------------------------------------------------------ reporting
    def error_text(self) -> str:
        """``"<class>: <message>"`` of the last error, or ``""``."""
        exc = self.error
        if exc is None:
            return ""
        message = exc.message if isinstance(exc, DeviceError) else str(exc)
        return f"{type(exc).__name__}: {message}"

    def frames(self) -> list[str]:
        """The last frames [hex] carried by the last error, if it is a :class:`DeviceError`."""
        exc = self.error
        return list(exc.frames_hex) if isinstance(exc, DeviceError) else []

    def prune(self, now: float) -> None:
        """Drop stamps older than the rate window (called by the poll loop only)."""
        while self.stamps and self.stamps[0] < now - RATE_WINDOW_S:
            self.stamps.popleft()

    def rate_hz(self, now: float) -> float:
        """Good readings per second over the last RATE_WINDOW_S (read-only)."""
        span = min(RATE_WINDOW_S, now - self.t_started)
        return len(self.stamps) / span if span > 0 else 0.0

    def status(self, now: float) -> dict[str, Any]:
        """The device's entry of :meth:`daemon.sampler.Sampler.status` (ages at ``now``)."""
        value: Any = list(self.value) if isinstance(self.value, tuple) else self.value
        reading = None
        if self.t_mono is not None:
            reading = {
                "value": value,
                "over_range": self.over_range,
                "age_s": now - self.t_mono,
                "t_wall": self.t_wall,
            }
        error = None
        if self.error is not None:
            message = self.error.message if isinstance(self.error, DeviceError) else str(self.error)
            error = {
                "class": type(self.error).__name__,
                "message": message,
                "frames_hex": self.frames(),
                "age_s": None if self.error_mono is None else now - self.error_mono,
                "t_wall": self.error_wall,
            }
        return {
            "name": self.name,
            "role": self.role,
            "driver": self.kind,
            "maker": self.maker,
            "state": self.state,
            "connected": self.state == "ok",
            "waiting_for": self.no_data,
            "last_reading": reading,
            "last_error": error,
            "poll_rate_hz": self.rate_hz(now),
            "polls": self.polls,
            "errors": sum(self.errors.values()),
            "errors_by_class": dict(self.errors),
        }


__all__ = ["RATE_WINDOW_S", "Device", "EventCallback", "Role"]
