"""FANUC R-30iB Plus through the Remote Motion Interface (RMI, option R912).

Packets (Remote Motion Interface OPERATOR'S MANUAL B-84184EN/03, sections 2.2-2.3 and
A.1; the field names also match FANUC's own C++ client, ``rmi/packets.hpp``): one JSON
object per packet, ASCII, terminated by ``\\r\\n``; the first key is ``Communication``,
``Command`` or ``Instruction``.

1. Connect to port 16001 and send ``{"Communication": "FRC_Connect"}``. The reply
   ``{"Communication": "FRC_Connect", "ErrorID": 0, "PortNumber": 16002, "MajorVersion": n,
   "MinorVersion": m}`` names the port of the session; the controller then closes 16001.
   ``ErrorID`` 2556954 (RMIT-026) means another client holds the one RMI session.
2. Connect to ``PortNumber``. ``{"Command": "FRC_ReadJointAngles"}`` answers
   ``{"Command": "FRC_ReadJointAngles", "ErrorID": 0, "TimeTag": t, "JointAngle": {"J1": …,
   …, "J9": …}}`` in degrees (J7..J9: extended axes, ignored here). Since RMI major version 6
   the angles are the actual (encoder) position.
3. ``{"Communication": "FRC_Disconnect"}`` ends the session.

The controller may also send, unasked, ``FRC_Terminate`` (idle session closed, default after
60 min), ``FRC_SystemFault`` (the RMI program paused on an error) and ``FRC_Record`` (the
pendant's RMI Position Record key); the driver notes and skips them.

What this driver deliberately does not send: ``FRC_Initialize``. It creates and runs the
RMI_MOVE TP program and keeps program control until ``FRC_Abort``, which would stop the
operator's own program from running the calibration plan. ``FRC_ReadJointAngles`` needs only
the connection (manual 2.3: commands available once ``FRC_Connect`` is accepted).

Why the protocol is written here: the public Python client fanuc-rmi (0.3.1) is
blocking, prints every packet, appends every joint reading to a JSONL file in the working
directory, and reads the session port from a ``Port`` key where the manual (and FANUC's C++
client) say ``PortNumber``, so against a real controller it only works by falling back to
its default 16002. The protocol is a few JSON lines; asyncio with bounded waits and typed
errors is short to write. fanuc-rmi still cross-checks the emulated face in the tests.

Late replies: RMI command replies carry no request id (``TimeTag`` is the controller's
clock, not an echo), but replies come in request order on one TCP stream. After a request
got no reply in time, the next request is preceded by a marker, ``FRC_GetStatus``, and every
``FRC_ReadJointAngles`` reply before the marker's reply is discarded (it answers an
abandoned request); no joint request is sent while a marker is outstanding. Only a marker
answered with ``ErrorID`` 0 counts: the controller accepts a command only when the previous
one is done (else RMIT-027, Wait for Command Done, possibly before the earlier reply), so an
accepted marker comes after every earlier reply; a refused one is followed by another. A
reply is thus never attributed to the wrong request, and a dropped reply costs no reconnect.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import math
import time
from typing import Annotated, Any, Literal

from pydantic import Field

from drivers.robot_link import LinkConfig, LinkedRobot, LinkLost, Unattributable

TERMINATOR = b"\r\n"
#: Longest packet line accepted [bytes] (a joint reply is ~250).
MAX_LINE = 4096
FIRST_KEYS = ("Communication", "Command", "Instruction")

#: RMI ErrorIDs (manual appendix A.1) used here.
RMIT_INVALID_COMMAND = 2556941  # RMIT-013 Invalid RMI Command
RMIT_INVALID_TEXT = 2556950  # RMIT-022 Invalid Text String
RMIT_ALREADY_CONNECTED = 2556954  # RMIT-026 Robot is Already Connected
RMIT_INVALID_GROUP = 2556967  # RMIT-039 Invalid Group Number
ERROR_NAMES = {
    RMIT_INVALID_COMMAND: "RMIT-013 Invalid RMI Command",
    RMIT_INVALID_TEXT: "RMIT-022 Invalid Text String",
    2556953: "RMIT-025 Remote Device Disconnected",
    RMIT_ALREADY_CONNECTED: "RMIT-026 Robot is Already Connected",
    2556955: "RMIT-027 Wait for Command Done",
    RMIT_INVALID_GROUP: "RMIT-039 Invalid Group Number",
}
JOINT_KEYS = ("J1", "J2", "J3", "J4", "J5", "J6")


def encode_packet(packet: dict[str, Any]) -> bytes:
    """One packet as a compact JSON line with ``\\r\\n``; the first key must be one of
    ``Communication``, ``Command``, ``Instruction``."""
    if not packet or next(iter(packet)) not in FIRST_KEYS:
        raise ValueError(f"packet: first key must be one of {FIRST_KEYS}")
    return json.dumps(packet, separators=(",", ":")).encode("ascii") + TERMINATOR


def decode_packet(line: bytes) -> dict[str, Any]:
    """A JSON object from one line (``\\r\\n`` optional).

    Raises
    ------
    ValueError
        Not ASCII JSON, not an object, or a first key other than ``Communication``,
        ``Command``, ``Instruction``.
    """
    text = line.decode("ascii").strip()
    obj = json.loads(text, parse_constant=_refuse_constant)
    if not isinstance(obj, dict) or not obj:
        raise ValueError(f"RMI packet is not a JSON object: {text[:60]!r}")
    first = next(iter(obj))
    if first not in FIRST_KEYS:
        raise ValueError(f"RMI packet's first key is {first!r}, not one of {FIRST_KEYS}")
    return obj


def _refuse_constant(name: str) -> float:
    raise ValueError(f"RMI packet holds {name}, which is not JSON")


def error_text(error_id: int) -> str:
    """``"RMIT-026 Robot is Already Connected"`` for a known ErrorID, else the number."""
    return ERROR_NAMES.get(error_id, f"ErrorID {error_id}")


def error_id_of(packet: dict[str, Any]) -> int:
    """The packet's ``ErrorID`` (an integer). Raises ``ValueError`` if absent or not one."""
    value = packet.get("ErrorID")
    if not isinstance(value, int) or isinstance(value, bool):
        raise ValueError(f"ErrorID: expected an integer, got {value!r}")
    return value


def session_port(reply: dict[str, Any]) -> int:
    """``PortNumber`` of an ``FRC_Connect`` reply with ``ErrorID`` 0.

    Raises ``ValueError`` (not an FRC_Connect reply, no valid port) or
    :class:`RmiError` (``ErrorID`` not 0).
    """
    if reply.get("Communication") != "FRC_Connect":
        raise ValueError(f"expected the FRC_Connect reply, got {_kind(reply)}")
    code = error_id_of(reply)
    if code != 0:
        raise RmiError("FRC_Connect", code)
    port = reply.get("PortNumber")
    if not isinstance(port, int) or isinstance(port, bool) or not 1 <= port <= 65535:
        raise ValueError(f"PortNumber: expected 1..65535, got {port!r}")
    return port


def joint_angles(reply: dict[str, Any]) -> tuple[float, float, float, float, float, float]:
    """J1..J6 [deg] of an ``FRC_ReadJointAngles`` reply.

    Raises :class:`RmiError` for ``ErrorID`` not 0, ``ValueError`` for a missing or
    non-numeric J1..J6 (named), a ``JointAngle`` that is not an object, or a non-finite value.
    """
    if reply.get("Command") != "FRC_ReadJointAngles":
        raise ValueError(f"expected the FRC_ReadJointAngles reply, got {_kind(reply)}")
    code = error_id_of(reply)
    if code != 0:
        raise RmiError("FRC_ReadJointAngles", code)
    angles = reply.get("JointAngle")
    if not isinstance(angles, dict):
        raise ValueError(f"JointAngle: expected an object, got {angles!r}"[:120])
    out: list[float] = []
    for key in JOINT_KEYS:
        value = angles.get(key)
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ValueError(f"JointAngle.{key}: expected a number, got {value!r}")
        if not math.isfinite(value):
            raise ValueError(f"JointAngle.{key}: not finite ({value!r})")
        out.append(float(value))
    return out[0], out[1], out[2], out[3], out[4], out[5]


def _kind(packet: dict[str, Any]) -> str:
    first = next(iter(packet))
    return f"{first}={packet[first]!r}"


class RmiError(Exception):
    """The controller answered a packet with a non-zero ``ErrorID``."""

    def __init__(self, packet_name: str, error_id: int) -> None:
        super().__init__(f"{packet_name}: {error_text(error_id)}")
        self.packet_name = packet_name
        self.error_id = error_id


class FanucRmiConfig(LinkConfig):
    """Configuration of :class:`FanucRmiRobot` (``[robot] kind = "fanuc-rmi"``).

    ``host``/``port``: the controller and its RMI connect port (16001; the session port comes
    from the ``FRC_Connect`` reply). ``group``: the motion group read (1..8; 1 is sent as the
    manual's default, i.e. without the optional ``Group`` key). No credentials: RMI has none.
    Timeouts, retries, back-off and ``max_unchanged_s``:
    :class:`drivers.robot_link.LinkConfig` (``timeout_s`` bounds the whole session opening).
    """

    kind: Literal["fanuc-rmi"] = "fanuc-rmi"
    port: Annotated[int, Field(ge=1, le=65535)] = 16001
    group: Annotated[int, Field(ge=1, le=8)] = 1


#: The marker command sent after a silent request (see the module docstring), and the pause
#: before another marker when one is refused [s].
MARKER = "FRC_GetStatus"
MARKER_PAUSE_S = 0.01


class FanucRmiRobot(LinkedRobot):
    """Asyncio driver of a FANUC controller through RMI (reads ``FRC_ReadJointAngles``); the
    link policy (retries, back-off, stale joints) is :class:`drivers.robot_link.LinkedRobot`."""

    #: The robot maker whose controller this driver reads (the robot library's words).
    MAKER = "fanuc"

    def __init__(self, config: FanucRmiConfig) -> None:
        super().__init__(config)
        self.config = config
        self.joints_what = "FRC_ReadJointAngles"
        self._reader: asyncio.StreamReader | None = None
        self._writer: asyncio.StreamWriter | None = None
        #: A request got no reply in time: the next one is preceded by a marker.
        self._unsynced = False
        #: The session port of the last session opened.
        self.session_port: int | None = None
        #: Replies discarded as answers to abandoned requests (or markers) [count].
        self.late_discarded = 0
        #: ``FRC_SystemFault`` packets received (their SequenceID), newest last.
        self.system_faults: list[int] = []

    def _is_open(self) -> bool:
        return self._writer is not None and not self._writer.is_closing()

    def _request(self) -> dict[str, Any]:
        packet: dict[str, Any] = {"Command": "FRC_ReadJointAngles"}
        if self.config.group != 1:
            packet["Group"] = self.config.group
        return packet

    async def _open(self) -> None:
        """``FRC_Connect`` on the connect port, then connect to the session port. A refusal
        (RMIT-026: another client holds the one session) or an answer that is not an
        FRC_Connect reply is a :class:`LinkLost` naming it (the caller makes it a
        :class:`~drivers.errors.RobotLinkDown`)."""
        cfg = self.config
        reader, writer = await asyncio.open_connection(cfg.host, cfg.port)
        try:
            packet = encode_packet({"Communication": "FRC_Connect"})
            self.frames.add("tx", packet)
            writer.write(packet)
            await writer.drain()
            line = await reader.readuntil(TERMINATOR)
            self.frames.add("rx", line)
        except asyncio.IncompleteReadError as exc:
            raise LinkLost("the connect port closed before answering FRC_Connect") from exc
        finally:
            writer.close()
        try:
            port = session_port(decode_packet(line))
        except RmiError as exc:
            raise LinkLost(f"FRC_Connect refused: {exc}") from exc
        except (ValueError, UnicodeDecodeError) as exc:
            raise LinkLost(f"FRC_Connect answered with no usable session port: {exc}") from exc
        self._reader, self._writer = await asyncio.open_connection(cfg.host, port)
        self.session_port = port
        self._unsynced = False
        self.frames.note(f"RMI session on port {port}")

    async def _close(self) -> None:
        """``FRC_Disconnect`` (best effort, its reply awaited at most ``fast_reply_timeout_s``),
        then close the session's connection."""
        reader, writer = self._reader, self._writer
        self._reader = self._writer = None
        if writer is None:
            return
        with contextlib.suppress(Exception):
            if not writer.is_closing():
                writer.write(encode_packet({"Communication": "FRC_Disconnect"}))
                await writer.drain()
                if reader is not None:
                    async with asyncio.timeout(self.config.fast_reply_timeout_s):
                        await reader.readuntil(TERMINATOR)
        writer.close()
        with contextlib.suppress(Exception):
            await writer.wait_closed()

    async def _request_joints(self, timeout_s: float) -> tuple[float, ...]:
        """One ``FRC_ReadJointAngles`` → J1..J6 [deg].

        Raises :class:`TimeoutError` (no reply in time; the next call re-synchronises with a
        marker first), :class:`RobotProtocolError` (``ErrorID`` not 0 as ``.code``, a
        malformed reply), :class:`Unattributable` (an unreadable or unexpected packet),
        :class:`LinkLost` (connection lost, or the controller sent ``FRC_Terminate``).
        """
        if self._reader is None or self._writer is None:
            raise LinkLost("not connected")
        deadline = time.monotonic() + timeout_s
        try:
            while self._unsynced:
                await self._send({"Command": MARKER})
                marker = await self._await_reply(MARKER, deadline)
                if marker.get("ErrorID") == 0:
                    self._unsynced = False
                else:  # refused (RMIT-027): an earlier command is still running
                    self.frames.note(f"marker refused ({marker.get('ErrorID')}); retrying")
                    await asyncio.sleep(min(MARKER_PAUSE_S, max(deadline - time.monotonic(), 0)))
            await self._send(self._request())
            reply = await self._await_reply("FRC_ReadJointAngles", deadline)
        except TimeoutError:
            self._unsynced = True
            raise
        except (OSError, asyncio.IncompleteReadError) as exc:
            raise LinkLost(repr(exc)) from exc
        except asyncio.LimitOverrunError as exc:
            raise Unattributable(f"RMI line longer than the reader's limit: {exc}") from exc
        try:
            return joint_angles(reply)
        except RmiError as exc:
            raise self.protocol_error(str(exc), code=exc.error_id) from exc
        except ValueError as exc:
            raise self.protocol_error(f"FRC_ReadJointAngles: {exc}") from exc

    async def _send(self, packet: dict[str, Any]) -> None:
        assert self._writer is not None
        data = encode_packet(packet)
        self.frames.add("tx", data)
        self._writer.write(data)
        await self._writer.drain()

    async def _await_reply(self, command: str, deadline: float) -> dict[str, Any]:
        """The next reply to ``command``; earlier replies to ``FRC_ReadJointAngles`` or the
        marker are discarded, unsolicited packets noted."""
        assert self._reader is not None
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise TimeoutError
            async with asyncio.timeout(remaining):
                line = await self._reader.readuntil(TERMINATOR)
            self.frames.add("rx", line)
            try:
                packet = decode_packet(line)
            except (ValueError, UnicodeDecodeError) as exc:
                raise Unattributable(f"unreadable RMI packet: {exc}") from exc
            first = next(iter(packet))
            name = packet[first]
            if first == "Command" and name == command:
                return packet
            if first == "Communication" and name == "FRC_Terminate":
                raise LinkLost("the controller ended the RMI session (FRC_Terminate)")
            if first == "Communication" and name == "FRC_SystemFault":
                seq = packet.get("SequenceID")
                self.system_faults.append(seq if isinstance(seq, int) else -1)
                self.frames.note("FRC_SystemFault: the RMI program paused on an error")
                continue
            if first == "Command" and name in ("FRC_ReadJointAngles", MARKER):
                self.late_discarded += 1
                self.frames.note(f"{name} reply discarded (answers an abandoned request)")
                continue
            if first == "Command" and name == "FRC_Record":
                self.frames.note("FRC_Record packet (pendant's Record key) skipped")
                continue
            raise Unattributable(f"unexpected packet {first}={name!r} awaiting {command}")
