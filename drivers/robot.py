"""The robot-driver interface, the joint reading, and the manual driver."""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Annotated, Literal, Protocol, runtime_checkable

from pydantic import BaseModel, ConfigDict, Field

from drivers.errors import RobotNoData, RobotProtocolError, RobotStale


@dataclass(frozen=True)
class JointReading:
    """Joint angles of a 6-axis robot.

    Attributes
    ----------
    joints_deg : tuple of 6 float
        Joint angles [deg] as the controller reports them.
    t_monotonic_s, t_wall : float
        :func:`time.monotonic` and :func:`time.time` when the reply was complete.
    """

    joints_deg: tuple[float, float, float, float, float, float]
    t_monotonic_s: float
    t_wall: float


def make_joints(values: Sequence[float], device: str) -> tuple[float, ...]:
    """Validate 6 finite joint angles; raises :class:`RobotProtocolError` otherwise."""
    if len(values) != 6:
        raise RobotProtocolError(device, f"expected 6 joint angles, got {len(values)}")
    out = tuple(float(v) for v in values)
    if not all(math.isfinite(v) for v in out):
        raise RobotProtocolError(device, f"non-finite joint angle in {out}")
    return out


def joint_reading(values: Sequence[float], device: str) -> JointReading:
    """A :class:`JointReading` stamped now."""
    j = make_joints(values, device)
    return JointReading((j[0], j[1], j[2], j[3], j[4], j[5]), time.monotonic(), time.time())


@runtime_checkable
class RobotDriver(Protocol):
    """What the daemon needs from a robot controller."""

    name: str

    async def connect(self) -> None:
        """Open the link now (otherwise the first :meth:`read_joints` does)."""

    async def read_joints(self) -> JointReading:
        """Current joint angles; raises :class:`~drivers.errors.RobotError` subclasses."""
        ...

    async def close(self) -> None:
        """Close the link."""


class StaleGuard:
    """Raise :class:`RobotStale` when the joints stay bit-identical longer than
    ``max_unchanged_s`` (``None`` disables: a robot at rest legitimately repeats values;
    use it for controllers whose encoders dither)."""

    def __init__(self, device: str, max_unchanged_s: float | None) -> None:
        self.device = device
        self.max_unchanged_s = max_unchanged_s
        self._last: tuple[float, ...] | None = None
        self._since = 0.0

    def check(self, reading: JointReading) -> JointReading:
        if self.max_unchanged_s is None:
            return reading
        if reading.joints_deg != self._last:
            self._last, self._since = reading.joints_deg, reading.t_monotonic_s
        elif reading.t_monotonic_s - self._since > self.max_unchanged_s:
            raise RobotStale(
                self.device,
                f"joint angles unchanged for {reading.t_monotonic_s - self._since:.1f} s",
            )
        return reading


class ManualRobotConfig(BaseModel):
    """Manual entry: joint angles come with the capture request."""

    model_config = ConfigDict(extra="forbid")

    kind: Literal["manual"] = "manual"
    name: str = "robot"
    max_age_s: Annotated[float | None, Field(gt=0)] = None


class ManualRobot:
    """Robot "driver" fed by :meth:`submit` (the REST capture request carries the angles)."""

    def __init__(self, config: ManualRobotConfig | None = None) -> None:
        self.config = config or ManualRobotConfig()
        self.name = self.config.name
        self._reading: JointReading | None = None

    async def connect(self) -> None:
        """Nothing to open."""

    def submit(self, joints_deg: Sequence[float]) -> JointReading:
        """Record joint angles [deg] posted by the operator or robot program."""
        self._reading = joint_reading(joints_deg, self.name)
        return self._reading

    async def read_joints(self) -> JointReading:
        """The last submitted angles.

        Raises
        ------
        RobotNoData
            Nothing submitted, or older than ``max_age_s``.
        """
        if self._reading is None:
            raise RobotNoData(self.name, "no joint angles submitted")
        age = time.monotonic() - self._reading.t_monotonic_s
        if self.config.max_age_s is not None and age > self.config.max_age_s:
            raise RobotNoData(self.name, f"submitted joint angles are {age:.1f} s old")
        return self._reading

    async def close(self) -> None:
        """Nothing to close."""
