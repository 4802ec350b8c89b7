"""Types shared by the sampler and the store: a capture, its raw readings, the sink protocol.

The data flow is one way (drivers → sampler → store): the sampler produces :class:`Capture`
objects and hands them to a :class:`CaptureSink` (the store implements it), which commits them
before the sampler acknowledges the capture.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Final, Literal, Protocol, get_args

from calib.sample_fields import Joints

#: How a capture was triggered: by the operator (``manual``) or by auto capture (``auto``).
#: The one home of the capture modes: the store's CHECK constraint and rows read them here.
CaptureMode = Literal["manual", "auto"]
CAPTURE_MODES: Final[tuple[str, ...]] = get_args(CaptureMode)

#: Why a capture was refused. ``http_status``: 409 (the cell is not in a state to capture)
#: or 503 (a device is down or its data are not trustworthy).
REJECTION_STATUS: dict[str, int] = {
    "moving": 409,  # the robot or the cable did not settle within capture_timeout_s
    "over_range": 409,  # the indicator flags over/under-range
    "not_new_pose": 409,  # auto mode: this pose was captured already
    "stale": 503,  # a reading is older than stale_s, or the two devices' stamps disagree
    "indicator_error": 503,  # the indicator raised a DeviceError (timeout, CRC, link down)
    "robot_error": 503,  # the robot controller raised a DeviceError
    "no_data": 503,  # no reading yet (sampler just started, manual robot without angles)
    "frozen": 503,  # the robot's joints stayed bit-identical while the cable length moved
}

RejectionReason = Literal[
    "moving",
    "over_range",
    "not_new_pose",
    "stale",
    "indicator_error",
    "robot_error",
    "no_data",
    "frozen",
]


@dataclass(frozen=True)
class RawReading:
    """One paired poll of both devices inside a capture window.

    Attributes
    ----------
    t_wall : float
        Wall-clock time of the length reading [s since the epoch].
    joints_deg : Joints
        Joint angles [deg].
    length_mm : float
        Cable length [mm].
    """

    t_wall: float
    joints_deg: Joints
    length_mm: float


@dataclass(frozen=True)
class Capture:
    """One calibration sample: the mean of the settled window.

    Attributes
    ----------
    joints_deg, joints_std_deg : Joints
        Mean and standard deviation of each joint angle over the window [deg].
    length_mm, length_std_mm : float
        Mean and standard deviation of the cable length over the window [mm].
    count : int
        Number of paired readings averaged.
    anchor : str
        Sensor position id (the CSV ``anchor`` column).
    t_start_wall, t_end_wall : float
        Wall-clock span of the window [s since the epoch].
    mode : {"manual", "auto"}
    raw : tuple of RawReading
        The readings averaged, oldest first.
    """

    joints_deg: Joints
    joints_std_deg: Joints
    length_mm: float
    length_std_mm: float
    count: int
    anchor: str
    t_start_wall: float
    t_end_wall: float
    mode: CaptureMode
    raw: tuple[RawReading, ...] = field(default=(), repr=False)


class CaptureRejected(Exception):
    """A capture was refused; ``reason`` is a key of :data:`REJECTION_STATUS`.

    Attributes
    ----------
    reason : str
    detail : str
        Human-readable cause, naming the device and its last error when there is one.
    device : str or None
        The device at fault, if any.
    """

    def __init__(self, reason: RejectionReason, detail: str, device: str | None = None) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason: RejectionReason = reason
        self.detail = detail
        self.device = device

    @property
    def http_status(self) -> int:
        """409 or 503, see :data:`REJECTION_STATUS`."""
        return REJECTION_STATUS[self.reason]


class CaptureSink(Protocol):
    """Where the sampler puts what it observes. :class:`daemon.store.Store` implements it.

    Every method commits before it returns; they are called from the sampler's event loop and
    must be quick (a single SQLite transaction).
    """

    def store_capture(self, campaign_id: int, capture: Capture) -> Mapping[str, Any]:
        """Commit a capture (sample row plus its raw readings); returns the sample row."""
        ...

    def record_rejection(
        self,
        campaign_id: int | None,
        reason: str,
        detail: str,
        device: str | None,
        joints_deg: Sequence[float] | None = None,
    ) -> None:
        """Record a refused capture (reason, detail) in the events table, with the pose it
        was refused at when the robot's joints are known (6 floats [deg]: a plan's progress
        reads them, :mod:`calib.planning.progress`)."""
        ...

    def record_event(
        self, kind: str, device: str | None, message: str, detail: dict[str, Any] | None = None
    ) -> None:
        """Record a device event: ``kind`` is e.g. ``device_error``, ``link_down``,
        ``link_up`` (a reconnect), ``sampler_started``; ``detail`` may carry ``frames_hex``."""
        ...
