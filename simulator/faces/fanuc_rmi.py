"""EMULATED FANUC Remote Motion Interface (RMI) serving the emulated cell's robot.

Two listeners, as on the controller: the connect port (16001 on a real controller; the
endpoint in READY) answers ``FRC_Connect`` with the session port's number and closes; the
session port (16002 on a real controller; here a free port unless given) carries the session.
Packets are the JSON lines of :mod:`drivers.fanuc_rmi` (manual B-84184EN/03).

Session rules kept from the manual: one session at a time (a second ``FRC_Connect`` while one
is granted or open gets ErrorID RMIT-026); the session port takes a client only after an
accepted ``FRC_Connect``; the session ends with ``FRC_Disconnect`` or when its client closes.
A grant not used within ``GRANT_S`` lapses.

Commands answered: ``FRC_ReadJointAngles`` (the cell's reported joints [deg], frozen while
``robot_frozen``; J7..J9 0; ``TimeTag`` in ms of the emulation's clock; ``Group`` other than
1 gets RMIT-039), ``FRC_GetStatus``, ``FRC_Initialize``, ``FRC_Abort``, ``FRC_Reset``,
``FRC_SetUFrameUTool``, ``FRC_GetUFrameUTool``, ``FRC_SetOverRide``. Other commands of the
manual get their own name back with RMIT-013 (the emulation lacks them), instructions
(motion) get RMIT-020: this face reports joints, it runs no RMI_MOVE program. A line that is
not a JSON object whose first key is ``Communication``/``Command``/``Instruction`` gets
``{"Command": "Unknown", "ErrorID": RMIT-022}`` (manual 2.4.19).

Faults: the robot fault settings (drops, delays, late replies) apply to every reply on the
session port; the connect port's reply is never dropped (a driver's retries are about the
session). ``link_down`` takes both listeners and any session away.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from typing import Any

from drivers.fanuc_rmi import (
    RMIT_ALREADY_CONNECTED,
    RMIT_INVALID_COMMAND,
    RMIT_INVALID_GROUP,
    RMIT_INVALID_TEXT,
    TERMINATOR,
    decode_packet,
    encode_packet,
)
from simulator.cell import EmulatedCell
from simulator.config import ServerSection
from simulator.faces.base import FaceServer

log = logging.getLogger("cablecal.simulator")

#: RMI versions reported by ``FRC_Connect`` (major 6+: joint angles are the actual position).
MAJOR_VERSION, MINOR_VERSION = 7, 0
#: Seconds a granted session waits for its client on the session port.
GRANT_S = 10.0
RMIT_INVALID_OVERRIDE = 2556933  # RMIT-005 Invalid Speed Override
RMIT_INVALID_INSTRUCTION = 2556948  # RMIT-020 Invalid RMI Instruction


async def read_line(reader: asyncio.StreamReader) -> bytes:
    """One ``\\r\\n``-terminated line (at most the reader's limit, else ``ValueError``)."""
    try:
        return await reader.readuntil(TERMINATOR)
    except asyncio.LimitOverrunError as exc:
        raise ValueError("RMI line too long") from exc


class FanucRmiSession(FaceServer):
    """The session port of :class:`FanucRmiServer`."""

    label = "fanuc-rmi-session"

    def __init__(self, cell: EmulatedCell, section: ServerSection) -> None:
        super().__init__(cell, section)
        self.granted_at: float | None = None
        self.active = False
        self.override_pct = 100
        self.uframe, self.utool = 0, 1
        self.initialized = False
        self._t0 = time.monotonic()
        #: Session packets answered or dropped since start [count].
        self.requests = 0

    @property
    def busy(self) -> bool:
        """A session is open, or granted and not yet lapsed."""
        if self.active:
            return True
        return self.granted_at is not None and time.monotonic() - self.granted_at < GRANT_S

    def grant(self) -> None:
        self.granted_at = time.monotonic()

    async def stop(self) -> None:
        await super().stop()
        self.granted_at, self.active, self.initialized = None, False, False

    async def serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        if self.active or self.granted_at is None or not self.busy:
            return  # no FRC_Connect accepted for this client: closed at once
        self.granted_at, self.active = None, True
        try:
            while True:
                try:
                    line = await read_line(reader)
                except asyncio.IncompleteReadError:
                    return
                try:
                    request: dict[str, Any] | None = decode_packet(line)
                except (ValueError, UnicodeDecodeError):
                    request = None
                reply, end = self.answer(request)
                self.requests += 1
                await self.send(writer, encode_packet(reply))
                if end:
                    return
        finally:
            self.active = False

    def answer(self, request: dict[str, Any] | None) -> tuple[dict[str, Any], bool]:
        """The reply packet, and whether the session ends after it."""
        if request is None:
            return {"Command": "Unknown", "ErrorID": RMIT_INVALID_TEXT}, False
        first = next(iter(request))
        name = request[first]
        if first == "Communication":
            if name == "FRC_Disconnect":
                return {"Communication": "FRC_Disconnect", "ErrorID": 0}, True
            return {"Communication": str(name), "ErrorID": RMIT_INVALID_COMMAND}, False
        if first == "Instruction":
            seq = request.get("SequenceID", 0)
            return {
                "Instruction": str(name),
                "ErrorID": RMIT_INVALID_INSTRUCTION,
                "SequenceID": seq,
            }, False
        return self.command(str(name), request), False

    def command(self, name: str, request: dict[str, Any]) -> dict[str, Any]:
        """Reply to one ``Command`` packet."""
        group = request.get("Group")
        if group is not None and group != 1:
            return {"Command": name, "ErrorID": RMIT_INVALID_GROUP, "Group": group}
        extra: dict[str, Any] = {} if group is None else {"Group": group}
        if name == "FRC_ReadJointAngles":
            q = [float(v) for v in self.cell.reported_joints()]
            angles = {f"J{i + 1}": round(v, 6) for i, v in enumerate(q)}
            angles.update({"J7": 0.0, "J8": 0.0, "J9": 0.0})
            tag = int((time.monotonic() - self._t0) * 1000) % 2**31
            return {"Command": name, "ErrorID": 0, "TimeTag": tag, "JointAngle": angles, **extra}
        if name == "FRC_GetStatus":
            return {
                "Command": name,
                "ErrorID": 0,
                "ServoReady": 1,
                "TPMode": 0,
                "RMIMotionStatus": int(self.initialized),
                "ProgramStatus": 0 if self.initialized else 2,
                "SingleStepMode": 0,
                "NumberUTool": 10,
                "NextSequenceID": 1,
                "NumberUFrame": 9,
                "Override": self.override_pct,
            }
        if name == "FRC_Initialize":
            self.initialized = True
            return {"Command": name, "ErrorID": 0, "GroupMask": 1}
        if name in ("FRC_Abort", "FRC_Reset"):
            self.initialized = self.initialized and name == "FRC_Reset"
            return {"Command": name, "ErrorID": 0}
        if name == "FRC_SetUFrameUTool":
            self.uframe = int(request.get("UFrameNumber", self.uframe))
            self.utool = int(request.get("UToolNumber", self.utool))
            return {"Command": name, "ErrorID": 0, **extra}
        if name == "FRC_GetUFrameUTool":
            return {
                "Command": name,
                "ErrorID": 0,
                "UFrameNumber": self.uframe,
                "UToolNumber": self.utool,
                **extra,
            }
        if name == "FRC_SetOverRide":
            value = request.get("Value")
            if not isinstance(value, int) or isinstance(value, bool) or not 1 <= value <= 100:
                return {"Command": name, "ErrorID": RMIT_INVALID_OVERRIDE}
            self.override_pct = value
            return {"Command": name, "ErrorID": 0}
        return {"Command": name, "ErrorID": RMIT_INVALID_COMMAND}


class FanucRmiServer(FaceServer):
    """EMULATED FANUC RMI, ``[robot_fanuc_rmi]``: the connect port (READY's endpoint) and its
    session port (``session_port``; 0, the default: a free port)."""

    label = "fanuc-rmi"

    def __init__(self, cell: EmulatedCell, section: ServerSection, session_port: int = 0) -> None:
        super().__init__(cell, section)
        session = ServerSection(enabled=True, host=section.host, port=session_port)
        self.session = FanucRmiSession(cell, session)

    async def start(self) -> None:
        await super().start()
        await self.session.start()

    async def stop(self) -> None:
        await super().stop()
        await self.session.stop()

    async def serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            async with asyncio.timeout(GRANT_S):
                line = await read_line(reader)
        except (TimeoutError, asyncio.IncompleteReadError):
            return
        try:
            request = decode_packet(line)
        except (ValueError, UnicodeDecodeError):
            reply: dict[str, Any] = {"Command": "Unknown", "ErrorID": RMIT_INVALID_TEXT}
        else:
            first = next(iter(request))
            if first != "Communication" or request[first] != "FRC_Connect":
                reply = {first: request[first], "ErrorID": RMIT_INVALID_COMMAND}
            elif self.session.busy:
                reply = {"Communication": "FRC_Connect", "ErrorID": RMIT_ALREADY_CONNECTED}
            else:
                self.session.grant()
                reply = {
                    "Communication": "FRC_Connect",
                    "ErrorID": 0,
                    "PortNumber": self.session.port,
                    "MajorVersion": MAJOR_VERSION,
                    "MinorVersion": MINOR_VERSION,
                }
        writer.write(encode_packet(reply))
        with contextlib.suppress(ConnectionError):
            await writer.drain()


__all__ = ["FanucRmiServer", "FanucRmiSession"]
