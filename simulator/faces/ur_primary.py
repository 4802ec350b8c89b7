"""EMULATED Universal Robots primary interface (port 30001): the arm's own kinematic table.

A UR controller streams on its primary interface, to every client that connects, messages of
``int32 length`` (header included) + ``uint8 type`` + payload, big-endian (UR's "Client
Interfaces: Primary/Secondary" document; UR's ur_client_library parses them the same way):

- first a version message: type 20 (robot message), ``uint64 timestamp``, ``int8 source``,
  ``uint8 robot message type`` 3 (version), then the project name (``int8`` length + text),
  ``uint8 major, minor``, ``int32 bugfix, build`` and the build date (text to the end);
- then robot-state messages, type 16, at 10 Hz, each a run of sub-packages ``int32 length``
  (header included) + ``uint8 type`` + payload. This face sends JointData (1: per joint
  ``double q_actual, q_target, qd_actual``, ``float I, V, T_motor, T_micro``, ``uint8 mode``),
  CartesianInfo (4: ``double X, Y, Z, Rx, Ry, Rz`` [m, rad], then the TCP offset, six
  doubles) and KinematicsInfo (5: ``uint32 checksum[6]``, ``double dh_theta[6], dh_a[6],
  dh_d[6], dh_alpha[6]`` [rad, m], ``uint32 calibration_status``).

What it reports: the cell's TRUE table (nominal model plus the emulated errors), which is what
a real controller computes with, its factory calibration; the joints the cell reports and the
flange pose of the true table (the RTDE face's ``actual_TCP_pose`` is the hook point).
Checksums are a CRC-32 of each joint's four numbers and the calibration status 0: both only
carried through by clients. A model in another convention than classic DH has no UR table:
its robot-state messages then carry no KinematicsInfo.

Written from UR's document, apart from :mod:`drivers.ur_primary` (a driver's mistake then fails
against this face). It listens beside the RTDE face on that face's own loopback address
(:class:`simulator.faces.ur_rtde.UrRtdeServer` starts it), on UR's fixed port 30001.
"""

from __future__ import annotations

import asyncio
import contextlib
import struct
import time
import zlib

import numpy as np
from scipy.spatial.transform import Rotation

from simulator.faces.base import FaceServer

#: UR's fixed primary-interface port.
PORT = 30001
ROBOT_MESSAGE = 20
ROBOT_STATE = 16
VERSION_MESSAGE = 3
JOINT_DATA = 1
CARTESIAN_INFO = 4
KINEMATICS_INFO = 5
#: Robot-state messages a second.
RATE_HZ = 10.0
#: What the version message says (an e-Series controller, as the RTDE face).
VERSION = (5, 12, 0, 1101534)


def _message(kind: int, payload: bytes) -> bytes:
    return struct.pack(">iB", 5 + len(payload), kind) + payload


def _sub(kind: int, payload: bytes) -> bytes:
    return struct.pack(">iB", 5 + len(payload), kind) + payload


def version_message(now_s: float) -> bytes:
    """The version message a client gets first."""
    name = b"URControl"
    major, minor, bugfix, build = VERSION
    payload = struct.pack(">QbB", int(now_s * 1e6), -1, VERSION_MESSAGE)
    payload += struct.pack(">b", len(name)) + name
    payload += struct.pack(">BBii", major, minor, bugfix, build) + b"01-01-2026, 00:00:00"
    return _message(ROBOT_MESSAGE, payload)


def kinematics_info(dh: np.ndarray) -> bytes:
    """The KinematicsInfo sub-package of a table ``dh`` (6, 4): ``alpha_rad, a_mm, d_mm,
    theta_rad`` per joint."""
    rows = np.asarray(dh, dtype=float)
    checks = [zlib.crc32(rows[j].tobytes()) for j in range(6)]
    payload = struct.pack(">6I", *checks)
    payload += struct.pack(">6d", *rows[:, 3])  # theta [rad]
    payload += struct.pack(">6d", *(rows[:, 1] / 1000.0))  # a [m]
    payload += struct.pack(">6d", *(rows[:, 2] / 1000.0))  # d [m]
    payload += struct.pack(">6d", *rows[:, 0])  # alpha [rad]
    payload += struct.pack(">I", 0)
    return _sub(KINEMATICS_INFO, payload)


class UrPrimaryServer(FaceServer):
    """The EMULATED primary interface (see the module docstring)."""

    label = "ur-primary"

    def true_table(self) -> np.ndarray | None:
        """The cell's true classic-DH table (6, 4) [rad, mm], or None for another convention."""
        truth = self.cell.truth
        if truth.model.convention != "dh":
            return None
        table: np.ndarray = truth.model.dh_internal() + truth.theta[:24].reshape(6, 4)
        return table

    def state_message(self, now: float) -> bytes:
        """One robot-state message at ``now`` (monotonic [s])."""
        q_deg = self.cell.reported_joints(now)
        q = np.radians(q_deg)
        joints = b"".join(
            struct.pack(">dddffffB", q[j], q[j], 0.0, 0.0, 48.0, 35.0, 0.0, 253) for j in range(6)
        )
        x, y, z, a, b, c = self.cell.tcp_pose(q_deg)
        rotvec = Rotation.from_euler("xyz", [a, b, c], degrees=True).as_rotvec()
        cart = struct.pack(">12d", x / 1e3, y / 1e3, z / 1e3, *rotvec, *([0.0] * 6))
        body = _sub(JOINT_DATA, joints) + _sub(CARTESIAN_INFO, cart)
        table = self.true_table()
        if table is not None:
            body += kinematics_info(table)
        return _message(ROBOT_STATE, body)

    async def serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        del reader  # the primary interface only talks (scripts sent to it are not emulated)
        period_s = 1.0 / RATE_HZ
        with contextlib.suppress(ConnectionError):
            writer.write(version_message(time.time()))
            await writer.drain()
            while not writer.is_closing():
                await self.send(writer, self.state_message(time.monotonic()))
                await asyncio.sleep(period_s)


__all__ = ["PORT", "UrPrimaryServer", "kinematics_info", "version_message"]
