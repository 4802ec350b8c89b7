"""Late robot replies: a robot that answers, but whose newest joints are older than the settle
window (``settle_s``), cannot give a settled window, however long it stands still.

:class:`LateWatch` follows one robot device (not the manual one: its angles are typed in). The
indicator's poll loop asks it each cycle (:meth:`LateWatch.check`); a robot reading ends the
episode (:meth:`LateWatch.on_reading`). The start of each episode is a ``robot_late`` event,
a warning in the log and a count in ``cablecal_robot_late_total``; the status shows the robot
as ``late`` with the age of its joints. A robot in error is not late: its error episode
already says so.
"""

from __future__ import annotations

import logging
from typing import Any

from daemon import metrics
from daemon.sampler.devices import Device, EventCallback

log = logging.getLogger("cablecal.sampler")


class LateWatch:
    """Late-reply episodes of one robot device (see the module).

    Parameters
    ----------
    device : Device
        The robot's book-keeping (its state and the stamp of its last good reading).
    on_event : EventCallback
        Records the ``robot_late`` event.
    """

    def __init__(self, device: Device, on_event: EventCallback) -> None:
        self.device = device
        self.on_event = on_event
        self.late_since: float | None = None  # monotonic start of the episode
        self.episodes = 0
        self.counter = metrics.ROBOT_LATE.labels(device.name)

    def age_s(self, now: float) -> float | None:
        """Age of the robot's newest good joints at monotonic ``now`` [s], or None."""
        last = self.device.last_good_mono
        return None if last is None or self.device.state != "ok" else now - last

    def check(self, now: float, settle_s: float) -> bool:
        """Whether the robot is late at ``now``; the first check past ``settle_s`` starts an
        episode (event, log, metric)."""
        age = self.age_s(now)
        if age is None or age <= settle_s:
            if self.device.state != "ok":
                self.late_since = None
            return self.late_since is not None
        if self.late_since is None:
            self.late_since = now - age + settle_s
            self.episodes += 1
            self.counter.inc()
            dev = self.device
            message = (
                f"robot {dev.name}: no joint reading for {age:.2f} s, longer than the settle "
                f"window settle_s {settle_s:g} s; its replies come late, so no window settles"
            )
            log.warning(message, extra={"device": dev.name, "error": "robot_late"})
            self.on_event("robot_late", dev.name, message, {"age_s": age, "settle_s": settle_s})
        return True

    def on_reading(self, now: float) -> None:
        """A good robot reading arrived: the episode, if any, ends."""
        if self.late_since is not None:
            dev = self.device
            log.info(
                "robot %s answers in time again after %.2f s late",
                dev.name,
                now - self.late_since,
                extra={"device": dev.name},
            )
            self.late_since = None

    def status(self, now: float) -> dict[str, Any]:
        """``late`` (bool), ``late_age_s`` (age of the joints while late, else None) and
        ``late_episodes`` (count since start) for the robot's entry of the status."""
        late = self.late_since is not None
        return {
            "late": late,
            "late_age_s": self.age_s(now) if late else None,
            "late_episodes": self.episodes,
        }
