"""Typed device errors.

Every error a driver raises is a :class:`DeviceError`: it names the device and carries the
last frames exchanged with it (hex, oldest first) so a field report shows the bytes.
"""

from __future__ import annotations

from collections.abc import Sequence


class DeviceError(Exception):
    """A device did not deliver a valid value.

    Attributes
    ----------
    device : str
        Name of the device (from the driver's configuration).
    frames_hex : tuple of str
        The last frames exchanged, oldest first, each as ``"tx 01 03 …"`` or ``"rx …"``.
    """

    def __init__(self, device: str, message: str, frames_hex: Sequence[str] = ()) -> None:
        super().__init__(f"{device}: {message}")
        self.device = device
        self.message = message
        self.frames_hex: tuple[str, ...] = tuple(frames_hex)

    def report(self) -> str:
        """The message followed by the recorded frames, one per line."""
        return "\n".join([str(self), *self.frames_hex])


class DeviceLinkDown(DeviceError):
    """The port or connection could not be opened, or was lost."""


class DeviceTimeout(DeviceError):
    """No complete, valid reply arrived within the timeout."""


class DeviceProtocolError(DeviceError):
    """A reply arrived but is malformed, or the device answered with an error."""


class IndicatorError(DeviceError):
    """Base class of indicator errors."""


class IndicatorLinkDown(IndicatorError, DeviceLinkDown):
    """The serial port (or socket) of the indicator is not available."""


class IndicatorTimeout(IndicatorError, DeviceTimeout):
    """Bytes arrived but no complete frame within the timeout."""


class IndicatorNoReply(IndicatorTimeout):
    """Not a single byte came back within the timeout."""


class IndicatorCRCError(IndicatorTimeout):
    """Reply bytes arrived, but their CRC (or checksum) was wrong; the value was discarded."""


class IndicatorProtocolError(IndicatorError, DeviceProtocolError):
    """Modbus exception response, wrong byte count, or an undecodable frame."""


class IndicatorOverRange(IndicatorError):
    """The indicator flags over-range or under-range; the value is not a valid length."""


class RobotError(DeviceError):
    """Base class of robot-controller errors."""


class RobotLinkDown(RobotError, DeviceLinkDown):
    """The controller's TCP connection could not be opened, or was lost."""


class RobotTimeout(RobotError, DeviceTimeout):
    """The controller did not answer within the timeout."""


class RobotProtocolError(RobotError, DeviceProtocolError):
    """Malformed reply, or the controller answered with a non-zero error code.

    Attributes
    ----------
    code : int or None
        The controller's error code, when it sent one.
    """

    def __init__(
        self,
        device: str,
        message: str,
        frames_hex: Sequence[str] = (),
        code: int | None = None,
    ) -> None:
        super().__init__(device, message, frames_hex)
        self.code = code


class RobotStale(RobotError):
    """The joint angles have not changed for longer than ``max_unchanged_s``."""


class RobotNoData(RobotError):
    """Manual robot: no joint angles were submitted (or they are too old)."""
