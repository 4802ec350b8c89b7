"""Huashu (HSR) III-type controller, "SocketCmd" TCP text protocol.

Frames (design note §2): request ``i:<seq>,c:<command>@hs@``, reply
``i:<seq>,e:<error>,d:<data>@hs@`` (``e:0`` on success), unsolicited alarms with ``i:-1``.
``mot.getJntData(0)`` answers ``{j1,j2,j3,j4,j5,j6,}`` in degrees (trailing comma).

Lossy links (issue 11): a request whose reply does not come within its timeout is re-sent at
once, with a new sequence number, on the same connection (``retries``); the connection is
closed and re-opened only after ``reconnect_after_timeouts`` silent attempts in a row.

How replies are matched, and why a late reply is never taken for the retry's: every request
carries a fresh, increasing sequence number, which the controller echoes, and only a frame
with the current request's number is its reply. A late reply to a timed-out attempt carries
an older number and is discarded (noted in the frame log), whenever it arrives. A frame with a
*newer* number than any request sent cannot be attributed to anything (a confused peer): the
connection is closed and the command fails with :class:`RobotProtocolError`, so the stream
re-synchronises on a fresh connection instead of guessing; a malformed frame does the same. A
controller that does not echo the numbers is never read wrong, only never read (timeouts). A
partial frame at a timeout stays in the stream buffer and is completed, then discarded, by
the next attempt. Alarms (``i:-1``) are kept in :attr:`HuashuSocketCmdRobot.alarms`.
"""

from __future__ import annotations

import asyncio
import re
import time
from collections import deque
from dataclasses import dataclass
from typing import Annotated, Literal

from pydantic import Field

from drivers.robot_link import LinkConfig, LinkLost, StreamLinkedRobot, Unattributable

TERMINATOR = b"@hs@"
_REPLY = re.compile(r"^i:(-?\d+),e:(-?\d+),d:(.*)$", re.S)


def encode_request(seq: int, command: str) -> bytes:
    """``i:<seq>,c:<command>@hs@``."""
    if "@hs@" in command:
        raise ValueError("command: must not contain the terminator @hs@")
    return f"i:{seq},c:{command}@hs@".encode("ascii")


def decode_reply(frame: bytes) -> tuple[int, int, str]:
    """``(seq, error_code, data)`` of one frame (with or without the terminator).

    Raises
    ------
    ValueError
        Not of the form ``i:<int>,e:<int>,d:<text>``.
    """
    text = frame.decode("ascii", errors="strict")
    if text.endswith("@hs@"):
        text = text[:-4]
    match = _REPLY.match(text.strip())
    if match is None:
        raise ValueError(f"malformed SocketCmd frame {text!r}")
    return int(match.group(1)), int(match.group(2)), match.group(3)


def parse_float_list(data: str) -> list[float]:
    """``{a,b,c,}`` → ``[a, b, c]``; the braces and the trailing comma are optional."""
    body = data.strip()
    if body.startswith("{") and body.endswith("}"):
        body = body[1:-1]
    parts = [p.strip() for p in body.split(",")]
    if parts and parts[-1] == "":
        parts.pop()
    try:
        return [float(p) for p in parts]
    except ValueError as exc:
        raise ValueError(f"not a list of numbers: {data!r}") from exc


@dataclass(frozen=True)
class Alarm:
    """An unsolicited ``i:-1`` frame."""

    code: int
    text: str
    t_monotonic_s: float


class HuashuConfig(LinkConfig):
    """Configuration of :class:`HuashuSocketCmdRobot`; the link settings (timeouts, retries,
    back-off, ``max_unchanged_s``) are :class:`drivers.robot_link.LinkConfig`'s."""

    kind: Literal["huashu-socketcmd"] = "huashu-socketcmd"
    port: Annotated[int, Field(ge=1, le=65535)] = 23333
    joints_command: str = "mot.getJntData(0)"


class HuashuSocketCmdRobot(StreamLinkedRobot):
    """Asyncio driver of a Huashu controller over SocketCmd."""

    #: The robot maker whose controller this driver reads (the robot library's words).
    MAKER = "hsr"

    def __init__(self, config: HuashuConfig) -> None:
        super().__init__(config)
        self.config = config
        self.alarms: deque[Alarm] = deque(maxlen=32)
        self._seq = 0
        self.joints_what = config.joints_command

    async def command(self, command: str) -> str:
        """Send one command and return its data field.

        A silent attempt (no reply within its timeout) is retried at once with a new
        sequence number on the same connection (see the module docstring).

        Raises
        ------
        RobotLinkDown
        RobotTimeout
            No reply to ``1 + retries`` attempts.
        RobotProtocolError
            Malformed or unattributable frame, or ``e != 0`` (the code is in ``.code``).
        """

        async def attempt(timeout_s: float) -> str:
            code, data = await self._attempt(command, timeout_s)
            if code != 0:
                raise self.protocol_error(f"{command}: controller error {code}: {data}", code)
            return data

        return await self.call(attempt, command)

    async def _attempt(self, command: str, timeout_s: float) -> tuple[int, str]:
        """One request with a fresh sequence number; ``(error code, data)`` of its reply.

        Raises :class:`TimeoutError` when no reply comes within ``timeout_s`` (its late
        reply, if any, is discarded by a later attempt: its number is older),
        :class:`LinkLost` on a lost link, :class:`Unattributable` on a frame that cannot be
        attributed.
        """
        assert self._reader is not None and self._writer is not None
        self._seq = self._seq + 1 if self._seq < 2**31 - 1 else 1
        seq = self._seq
        request = encode_request(seq, command)
        self.frames.add("tx", request)
        deadline = time.monotonic() + timeout_s
        try:
            self._writer.write(request)
            await self._writer.drain()
            while True:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    raise TimeoutError
                async with asyncio.timeout(remaining):
                    frame = await self._reader.readuntil(TERMINATOR)
                self.frames.add("rx", frame)
                try:
                    r_seq, code, data = decode_reply(frame)
                except (ValueError, UnicodeDecodeError) as exc:
                    raise Unattributable(f"malformed frame: {exc}") from exc
                if r_seq == -1:
                    self.alarms.append(Alarm(code, data, time.monotonic()))
                elif r_seq == seq:
                    return code, data
                elif r_seq < seq:
                    self.frames.note(f"late reply to i:{r_seq} discarded")
                else:
                    raise Unattributable(
                        f"reply i:{r_seq} is newer than the request sent (i:{seq})"
                    )
        except TimeoutError:
            raise  # a subclass of OSError, but the link may well be up: the caller retries
        except (OSError, asyncio.IncompleteReadError, asyncio.LimitOverrunError) as exc:
            raise LinkLost(repr(exc)) from exc

    async def _request_joints(self, timeout_s: float) -> list[float]:
        """``joints_command`` → the first 6 values [deg]."""
        code, data = await self._attempt(self.config.joints_command, timeout_s)
        if code != 0:
            raise self.protocol_error(
                f"{self.config.joints_command}: controller error {code}: {data}", code
            )
        return self._six(data, "joint")

    def _six(self, data: str, what: str) -> list[float]:
        try:
            values = parse_float_list(data)
        except ValueError as exc:
            raise self.protocol_error(str(exc)) from exc
        if len(values) < 6:
            raise self.protocol_error(f"{len(values)} {what} values, expected 6")
        return values[:6]

    async def read_location(self) -> tuple[float, ...]:
        """``mot.getLocData(0)`` → X, Y, Z [mm], A, B, C [deg] of the TCP."""
        return tuple(self._six(await self.command("mot.getLocData(0)"), "location"))
