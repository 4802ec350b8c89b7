"""KUKA KR C2/KR C4 through KukaVarProxy: the OpenShowVar protocol on TCP port 7000.

KukaVarProxy is a small Windows program that runs on the controller's PC and gives TCP
clients the KRL variables through KUKA's CrossComm. It has no user, password or encryption:
whoever reaches port 7000 can read and write variables, so it belongs on a cell network.

Frames (big-endian; checked byte by byte against the proxy's source, ImtsSrl/KUKAVARPROXY
``src/frmMain.frm`` ``sockServer_Read`` and ``src/basMain.bas`` ``readMsg``, and against
the public client py_openshowvar 1.1.7)::

    request  id:u16  length:u16  function:u8  name_len:u16  name      [value_len:u16 value]
    reply    id:u16  length:u16  function:u8  value_len:u16 value     00 01 status:u8

``function`` 0 reads (no value part), 1 writes. ``length`` counts the bytes after the 4-byte
header. The reply echoes the request's ``id`` and ends with a 3-byte tail ``00 01 status``
(``status`` 1: done, 0: failed). The proxy's source counts the tail in the reply's
``length``; py_openshowvar's README shows a reply whose ``length`` leaves it out (another
proxy build), so both are accepted and anything else is a protocol error. A failed read
answers an empty value (the proxy's ``ShowVar`` returns ``""`` when CrossComm fails or does
not know the variable), so an empty value is an error here too, never a zero.

``$AXIS_ACT`` (type E6AXIS) is the axis-specific actual position, as a KRL struct string::

    {E6AXIS: A1 -92.22486, A2 -135.1067, A3 122.0934, A4 -9.729492, A5 0.0, A6 12.10981,
     E1 0.0, E2 0.0, E3 0.0, E4 0.0, E5 0.0, E6 0.0}

A1..A6 are the robot axes in degrees (KRL ``REAL``: 32-bit, printed to 7 significant
digits); E1..E6 are external axes and ignored. :func:`parse_e6axis` reads it strictly: a
missing, repeated or unknown component, a bad number or a different type name is a
:class:`RobotProtocolError` naming what was wrong.

Why the protocol is written here rather than through py_openshowvar: that client (1.1.7,
2021, unmaintained) is blocking with no timeout at all on its ``recv``, reads a reply with
one ``recv(256)`` (a reply split across TCP segments is cut), starts its message id at a
random number and returns ``None`` on a mismatched id or a failed status without saying
which. Polling a controller from the daemon's event loop needs asyncio, bounded waits and
typed errors, and the protocol is 7 bytes of header. py_openshowvar is still the
independent client that cross-checks our emulated proxy in the tests.

Late replies: every request carries a fresh message id (u16, wrapping), which the proxy
echoes; a reply with another id is a late reply to an abandoned request and is discarded, so
a value is never attributed to the wrong request (the same scheme as Huashu SocketCmd).
"""

from __future__ import annotations

import asyncio
import re
import struct
import time
from dataclasses import dataclass
from typing import Annotated, Literal

from pydantic import Field

from drivers.robot_link import LinkConfig, LinkLost, StreamLinkedRobot, Unattributable

#: Functions of the OpenShowVar protocol.
FUNCTION_READ, FUNCTION_WRITE = 0, 1
#: Reply tail: ``00 01`` then the status byte.
STATUS_OK, STATUS_FAILED = 1, 0
HEADER = struct.Struct(">HH")
#: Longest variable name or value the protocol's u16 length can carry [bytes].
MAX_FIELD = 0xFFFF - 5


def encode_read(msg_id: int, name: str) -> bytes:
    """Read request for variable ``name`` (ASCII) with message id ``msg_id`` (0..65535)."""
    raw = name.encode("ascii")
    if not 0 < len(raw) <= MAX_FIELD:
        raise ValueError(f"name: 1..{MAX_FIELD} ASCII bytes, got {len(raw)}")
    body = struct.pack(">BH", FUNCTION_READ, len(raw)) + raw
    return HEADER.pack(msg_id & 0xFFFF, len(body)) + body


def encode_write(msg_id: int, name: str, value: str) -> bytes:
    """Write request: variable ``name`` := ``value`` (both ASCII)."""
    raw_name, raw_value = name.encode("ascii"), value.encode("ascii")
    if not 0 < len(raw_name) + len(raw_value) <= MAX_FIELD - 2:
        raise ValueError("name and value: too long for one OpenShowVar frame")
    body = (
        struct.pack(">BH", FUNCTION_WRITE, len(raw_name))
        + raw_name
        + struct.pack(">H", len(raw_value))
        + raw_value
    )
    return HEADER.pack(msg_id & 0xFFFF, len(body)) + body


def encode_reply(msg_id: int, function: int, value: bytes, ok: bool) -> bytes:
    """Reply frame as the proxy sends it (``length`` counts the tail)."""
    body = (
        struct.pack(">BH", function, len(value))
        + value
        + bytes((0, 1, STATUS_OK if ok else STATUS_FAILED))
    )
    return HEADER.pack(msg_id & 0xFFFF, len(body)) + body


@dataclass(frozen=True)
class Reply:
    """One decoded reply frame (``ok``: status byte 1)."""

    msg_id: int
    function: int
    value: bytes
    ok: bool


def decode_reply(frame: bytes) -> Reply:
    """Decode one complete reply frame (header included).

    Raises
    ------
    ValueError
        Lengths that do not add up, a tail other than ``00 01 xx``, or a status other than
        0 or 1; the message names the field.
    """
    if len(frame) < 4 + 3 + 3:
        raise ValueError(f"reply of {len(frame)} bytes; the shortest is 10")
    msg_id, length = HEADER.unpack_from(frame)
    function, value_len = struct.unpack_from(">BH", frame, 4)
    expected = 7 + value_len + 3
    if len(frame) != expected:
        raise ValueError(f"value_len {value_len} gives a {expected}-byte frame, got {len(frame)}")
    if length not in (value_len + 6, value_len + 3):
        raise ValueError(
            f"length field {length} matches neither value_len+6 nor value_len+3 ({value_len})"
        )
    tail = frame[-3:]
    if tail[:2] != b"\x00\x01" or tail[2] not in (STATUS_OK, STATUS_FAILED):
        raise ValueError(f"reply tail {tail.hex(' ')}; expected 00 01 00 or 00 01 01")
    return Reply(
        msg_id=msg_id,
        function=function,
        value=bytes(frame[7 : 7 + value_len]),
        ok=tail[2] == STATUS_OK,
    )


def reply_frame_size(buf: bytes | bytearray) -> int:
    """Size of the reply frame at the front of ``buf`` [bytes], 0 until 7 bytes are there
    (the frame is complete when ``len(buf)`` reaches it)."""
    if len(buf) < 7:
        return 0
    return 7 + int.from_bytes(buf[5:7], "big") + 3


def split_request(buf: bytes) -> tuple[int, tuple[int, int, str, str | None] | None]:
    """One request from the front of ``buf`` (the emulated proxy's framer).

    Returns ``(used, request)``: ``used`` 0 when more bytes are needed; ``request`` is
    ``(msg_id, function, name, value)`` (``value`` None for reads), or None for a frame
    whose fields do not add up (``used`` bytes of it are skipped).
    """
    if len(buf) < 4:
        return 0, None
    msg_id, length = HEADER.unpack_from(buf)
    if len(buf) < 4 + length:
        return 0, None
    body = buf[4 : 4 + length]
    used = 4 + length
    try:
        function, name_len = struct.unpack_from(">BH", body)
        name = body[3 : 3 + name_len].decode("ascii")
        if len(name) != name_len or not name:
            return used, None
        value: str | None = None
        rest = body[3 + name_len :]
        if function == FUNCTION_WRITE:
            (value_len,) = struct.unpack_from(">H", rest)
            value = rest[2 : 2 + value_len].decode("ascii")
            if len(value) != value_len or len(rest) != 2 + value_len:
                return used, None
        elif rest:
            return used, None
    except (struct.error, UnicodeDecodeError):
        return used, None
    return used, (msg_id, function, name, value)


# --------------------------------------------------------------------------- E6AXIS
_NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
_STRUCT = re.compile(r"^\{\s*([A-Za-z0-9_]+)\s*:(.*)\}$", re.S)
_COMPONENT = re.compile(r"^([A-Za-z][A-Za-z0-9_]*)\s+(" + _NUMBER + r")$")
ROBOT_AXES = ("A1", "A2", "A3", "A4", "A5", "A6")
EXTERNAL_AXES = ("E1", "E2", "E3", "E4", "E5", "E6")


def parse_e6axis(text: str) -> tuple[float, float, float, float, float, float]:
    """A1..A6 [deg] of a KRL ``E6AXIS`` (or ``AXIS``) struct string.

    Raises
    ------
    ValueError
        Not ``{E6AXIS: A1 <num>, …}``; a component that is not ``NAME <number>``; A1..A6
        missing or repeated; a component other than A1..A6, E1..E6. The message names it.
    """
    match = _STRUCT.match(text.strip())
    if match is None:
        raise ValueError(f"not a KRL struct {{TYPE: …}}: {text[:60]!r}")
    type_name, body = match.group(1).upper(), match.group(2)
    if type_name not in ("E6AXIS", "AXIS"):
        raise ValueError(f"struct type {type_name}, expected E6AXIS")
    values: dict[str, float] = {}
    for part in body.split(","):
        item = part.strip()
        comp = _COMPONENT.match(item)
        if comp is None:
            raise ValueError(f"component {item!r} is not 'NAME number'")
        name = comp.group(1).upper()
        if name not in ROBOT_AXES and name not in EXTERNAL_AXES:
            raise ValueError(f"unknown component {name} in {type_name}")
        if name in values:
            raise ValueError(f"component {name} appears twice")
        values[name] = float(comp.group(2))
    missing = [a for a in ROBOT_AXES if a not in values]
    if missing:
        raise ValueError(f"{type_name} lacks {', '.join(missing)}")
    a1, a2, a3, a4, a5, a6 = (values[a] for a in ROBOT_AXES)
    return a1, a2, a3, a4, a5, a6


def krl_real(value: float) -> str:
    """``value`` as KRL prints a ``REAL`` (32-bit, 7 significant digits): ``-135.1067``,
    ``0.0``, ``1.23456E-05``."""
    single = struct.unpack(">f", struct.pack(">f", value))[0]
    text = f"{single:.7g}".upper()
    if "." not in text and "E" not in text and "N" not in text:
        text += ".0"
    return text


def format_e6axis(axes_deg: tuple[float, ...] | list[float]) -> str:
    """``{E6AXIS: A1 …, A6 …, E1 0.0, … E6 0.0}`` from 6 robot axes [deg]."""
    if len(axes_deg) != 6:
        raise ValueError(f"axes_deg: 6 values, got {len(axes_deg)}")
    parts = [f"{name} {krl_real(v)}" for name, v in zip(ROBOT_AXES, axes_deg, strict=True)]
    parts += [f"{name} 0.0" for name in EXTERNAL_AXES]
    return "{E6AXIS: " + ", ".join(parts) + "}"


class KukaVarProxyConfig(LinkConfig):
    """Configuration of :class:`KukaVarProxyRobot` (``[robot] kind = "kuka-varproxy"``).

    ``host``/``port``: the KukaVarProxy endpoint (the proxy listens on 7000). ``variable``:
    the E6AXIS variable read (``$AXIS_ACT``; ``$AXIS_ACT_MEAS`` for the measured position on
    KSS 8). No credentials: the protocol has none. Timeouts, retries, back-off and
    ``max_unchanged_s``: :class:`drivers.robot_link.LinkConfig`.
    """

    kind: Literal["kuka-varproxy"] = "kuka-varproxy"
    port: Annotated[int, Field(ge=1, le=65535)] = 7000
    variable: Annotated[
        str, Field(min_length=1, max_length=64, pattern=r"^[$A-Za-z0-9_.\[\]]+$")
    ] = "$AXIS_ACT"


class KukaVarProxyRobot(StreamLinkedRobot):
    """Asyncio driver of a KUKA controller through KukaVarProxy (reads ``$AXIS_ACT``); the
    link policy (retries, back-off, stale joints) is :class:`drivers.robot_link.LinkedRobot`."""

    #: The robot maker whose controller this driver reads (the robot library's words).
    MAKER = "kuka"

    def __init__(self, config: KukaVarProxyConfig) -> None:
        super().__init__(config)
        self.config = config
        self.joints_what = config.variable
        self._rx = bytearray()
        self._msg_id = 0
        #: Late replies (to an abandoned request) discarded since creation [count].
        self.late_discarded = 0

    async def _open(self) -> None:
        await super()._open()
        self._rx.clear()

    async def _request_joints(self, timeout_s: float) -> tuple[float, ...]:
        """One read of the configured variable → A1..A6 [deg].

        Raises :class:`TimeoutError` when no reply with this request's message id comes
        within ``timeout_s`` (a late reply to an earlier id is discarded whenever it comes),
        :class:`RobotProtocolError` for a failed read, an empty value or a malformed E6AXIS,
        :class:`Unattributable` for a frame whose lengths or tail do not add up,
        :class:`LinkLost` when the connection is lost.
        """
        if self._reader is None or self._writer is None:
            raise LinkLost("not connected")
        self._msg_id = (self._msg_id + 1) & 0xFFFF
        msg_id = self._msg_id
        request = encode_read(msg_id, self.config.variable)
        self.frames.add("tx", request)
        deadline = time.monotonic() + timeout_s
        try:
            self._writer.write(request)
            await self._writer.drain()
            while True:
                reply = await self._next_reply(deadline)
                if reply.msg_id == msg_id:
                    return self._joints_of(reply)
                self.late_discarded += 1
                self.frames.note(f"late reply to id {reply.msg_id} discarded")
        except TimeoutError:
            raise
        except (OSError, asyncio.IncompleteReadError) as exc:
            raise LinkLost(repr(exc)) from exc

    async def _next_reply(self, deadline: float) -> Reply:
        """The next complete reply frame (bytes kept across timeouts: a frame cut by a
        timeout is completed by the next call)."""
        assert self._reader is not None
        while True:
            size = reply_frame_size(self._rx)
            if size and len(self._rx) >= size:
                frame = bytes(self._rx[:size])
                del self._rx[:size]
                self.frames.add("rx", frame)
                try:
                    return decode_reply(frame)
                except ValueError as exc:
                    raise Unattributable(f"malformed frame: {exc}") from exc
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise TimeoutError
            async with asyncio.timeout(remaining):
                chunk = await self._reader.read(4096)
            if not chunk:
                raise asyncio.IncompleteReadError(bytes(self._rx), None)
            self._rx += chunk

    def _joints_of(self, reply: Reply) -> tuple[float, ...]:
        var = self.config.variable
        if not reply.ok:
            raise self.protocol_error(f"{var}: the proxy reports a failed read (status 0)")
        if not reply.value:
            raise self.protocol_error(
                f"{var}: empty value (unknown variable, or the proxy lost CrossComm)"
            )
        try:
            return parse_e6axis(reply.value.decode("ascii"))
        except (ValueError, UnicodeDecodeError) as exc:
            raise self.protocol_error(f"{var}: {exc}") from exc
