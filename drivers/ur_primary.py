"""Universal Robots primary interface (TCP port 30001): the arm's factory calibration.

The controller streams robot-state messages on its primary interface: ``int32 length``
(header included) + ``uint8 type`` (16 = robot state), then sub-packages, each ``int32
length`` (header included) + ``uint8 type`` + payload, all big-endian; other message types
(version, text, safety) are skipped by their length. Sub-package 5, **KinematicsInfo**, holds
``uint32 checksum[6]``, then ``double dh_theta[6], dh_a[6], dh_d[6], dh_alpha[6]`` [rad, m]
(the arm's whole calibrated DH table, as ROS's ur_calibration reads it: UniversalRobots'
ur_client_library, ``primary/robot_state/kinematics_info``), then ``uint32
calibration_status``. :func:`read_kinematics_info` connects, reads until the first
KinematicsInfo and closes; :func:`calib.robots.ur_factory.from_kinematics_info` turns it into
the arm's model file.
"""

from __future__ import annotations

import asyncio
import struct
from dataclasses import dataclass

PRIMARY_PORT = 30001
ROBOT_STATE = 16
KINEMATICS_INFO = 5
#: A robot-state message is a few kB; past this the stream is not the primary interface.
MAX_MESSAGE_BYTES = 1 << 16
_CHECKSUMS = struct.Struct(">6I")
_TABLE = struct.Struct(">24d")


class PrimaryInterfaceError(ValueError):
    """A byte stream that is not the primary interface, or no KinematicsInfo in time."""


@dataclass(frozen=True)
class KinematicsInfo:
    """The arm's calibrated DH table: per joint ``theta_rad``, ``a_m``, ``d_m``,
    ``alpha_rad`` (6 each), the joints' ``checksums`` and the ``calibration_status`` (None when
    the package is too short to carry it)."""

    checksums: tuple[int, ...]
    theta_rad: tuple[float, ...]
    a_m: tuple[float, ...]
    d_m: tuple[float, ...]
    alpha_rad: tuple[float, ...]
    calibration_status: int | None


def parse_kinematics_info(payload: bytes) -> KinematicsInfo:
    """A KinematicsInfo sub-package's payload (after its 5-byte header)."""
    need = _CHECKSUMS.size + _TABLE.size
    if len(payload) < need:
        raise PrimaryInterfaceError(f"KinematicsInfo of {len(payload)} bytes, expected >= {need}")
    checksums = _CHECKSUMS.unpack_from(payload, 0)
    table = _TABLE.unpack_from(payload, _CHECKSUMS.size)
    status = None
    if len(payload) >= need + 4:
        (status,) = struct.unpack_from(">I", payload, need)
    return KinematicsInfo(checksums, table[0:6], table[6:12], table[12:18], table[18:24], status)


def kinematics_info_in(message: bytes) -> KinematicsInfo | None:
    """The KinematicsInfo of one whole message (header included), or None when it has none."""
    if len(message) < 5:
        raise PrimaryInterfaceError(f"message of {len(message)} bytes, shorter than its header")
    length, kind = struct.unpack_from(">iB", message, 0)
    if length != len(message):
        raise PrimaryInterfaceError(f"message says {length} bytes, has {len(message)}")
    if kind != ROBOT_STATE:
        return None
    at = 5
    while at < length:
        if at + 5 > length:
            raise PrimaryInterfaceError(f"sub-package header cut at byte {at}")
        size, sub = struct.unpack_from(">iB", message, at)
        if size < 5 or at + size > length:
            raise PrimaryInterfaceError(f"sub-package at byte {at} says {size} bytes")
        if sub == KINEMATICS_INFO:
            return parse_kinematics_info(message[at + 5 : at + size])
        at += size
    return None


async def read_kinematics_info(
    host: str, port: int = PRIMARY_PORT, timeout_s: float = 5.0
) -> KinematicsInfo:
    """Connect to the primary interface and return the first KinematicsInfo sent.

    Raises
    ------
    PrimaryInterfaceError
        None within ``timeout_s``, or a stream that is not the primary interface.
    OSError
        The connection failed.
    """
    try:
        async with asyncio.timeout(timeout_s):
            reader, writer = await asyncio.open_connection(host, port)
            try:
                while True:
                    head = await reader.readexactly(5)
                    (length,) = struct.unpack_from(">i", head, 0)
                    if not 5 <= length <= MAX_MESSAGE_BYTES:
                        raise PrimaryInterfaceError(
                            f"{host}:{port}: a message of {length} bytes: not a UR primary "
                            "interface"
                        )
                    body = await reader.readexactly(length - 5)
                    info = kinematics_info_in(head + body)
                    if info is not None:
                        return info
            finally:
                writer.close()
    except TimeoutError as exc:
        raise PrimaryInterfaceError(
            f"{host}:{port}: no KinematicsInfo within {timeout_s} s"
        ) from exc
    except asyncio.IncompleteReadError as exc:
        raise PrimaryInterfaceError(f"{host}:{port}: the controller closed the stream") from exc


__all__ = [
    "KinematicsInfo",
    "PrimaryInterfaceError",
    "kinematics_info_in",
    "parse_kinematics_info",
    "read_kinematics_info",
]
