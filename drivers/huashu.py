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
import contextlib
import re
import time
from collections import deque
from dataclasses import dataclass
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field

from drivers.backoff import ReconnectBackoff, SilentAttempts
from drivers.errors import RobotLinkDown, RobotProtocolError, RobotTimeout
from drivers.frames import FrameLog
from drivers.robot import JointReading, StaleGuard, joint_reading

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


class HuashuConfig(BaseModel):
    """Configuration of :class:`HuashuSocketCmdRobot`.

    ``timeout_s`` bounds the TCP connect and the last attempt's wait for a reply [s];
    ``fast_reply_timeout_s`` the wait of every earlier attempt (capped at ``timeout_s``) [s];
    ``retries`` immediate re-sends on the same connection after a silent attempt [count];
    ``reconnect_after_timeouts`` silent attempts in a row (across commands) after which the
    connection is closed and re-opened [count]. See :class:`drivers.backoff.SilentAttempts`.
    """

    model_config = ConfigDict(extra="forbid")

    kind: Literal["huashu-socketcmd"] = "huashu-socketcmd"
    name: str = "robot"
    host: str = "127.0.0.1"
    port: Annotated[int, Field(ge=1, le=65535)] = 23333
    timeout_s: Annotated[float, Field(gt=0)] = 1.0
    fast_reply_timeout_s: Annotated[float, Field(gt=0)] = 0.2
    retries: Annotated[int, Field(ge=0)] = 2
    reconnect_after_timeouts: Annotated[int, Field(ge=1)] = 3
    joints_command: str = "mot.getJntData(0)"
    reconnect_min_s: Annotated[float, Field(gt=0)] = 0.1
    reconnect_max_s: Annotated[float, Field(gt=0)] = 1.0
    max_unchanged_s: Annotated[float | None, Field(gt=0)] = None
    frame_log_size: Annotated[int, Field(ge=1)] = 16


class HuashuSocketCmdRobot:
    """Asyncio driver of a Huashu controller over SocketCmd."""

    def __init__(self, config: HuashuConfig) -> None:
        self.config = config
        self.name = config.name
        self.frames = FrameLog(config.frame_log_size)
        self.alarms: deque[Alarm] = deque(maxlen=32)
        self._reader: asyncio.StreamReader | None = None
        self._writer: asyncio.StreamWriter | None = None
        self._seq = 0
        self._backoff = ReconnectBackoff(config.reconnect_min_s, config.reconnect_max_s)
        #: Retry policy and its counters (silent attempts, reads saved by a retry).
        self.attempts = SilentAttempts(
            config.retries,
            config.reconnect_after_timeouts,
            min(config.fast_reply_timeout_s, config.timeout_s),
            config.timeout_s,
        )
        self._lock = asyncio.Lock()
        #: Successful TCP connects since creation [count] (the first one included).
        self.connects = 0
        self._stale = StaleGuard(config.name, config.max_unchanged_s)

    @property
    def connected(self) -> bool:
        return self._writer is not None and not self._writer.is_closing()

    async def connect(self) -> None:
        """Open the TCP connection now. Raises :class:`RobotLinkDown`."""
        async with self._lock:
            await self._ensure_connected(force=True)

    async def _ensure_connected(self, force: bool = False) -> None:
        if self.connected:
            return
        cfg = self.config
        wait_s = self._backoff.remaining_s(time.monotonic())
        if not force and wait_s > 0:
            raise RobotLinkDown(
                self.name,
                f"{cfg.host}:{cfg.port} down; next reconnect in {wait_s:.2f} s",
                self.frames.snapshot(),
            )
        try:
            self._reader, self._writer = await asyncio.wait_for(
                asyncio.open_connection(cfg.host, cfg.port), cfg.timeout_s
            )
        except (TimeoutError, OSError) as exc:
            self._backoff.failed()
            self.frames.note(f"connect {cfg.host}:{cfg.port} failed: {exc}")
            raise RobotLinkDown(
                self.name, f"cannot connect to {cfg.host}:{cfg.port}: {exc}", self.frames.snapshot()
            ) from exc
        self._backoff.succeeded()
        self.connects += 1
        self.attempts.reset()
        self.frames.note(f"connected {cfg.host}:{cfg.port}")

    async def close(self) -> None:
        """Close the connection."""
        if self._writer is not None:
            self._writer.close()
            with contextlib.suppress(Exception):
                await self._writer.wait_closed()
        self._reader = self._writer = None

    def _drop(self, why: str) -> None:
        self.frames.note(why)
        if self._writer is not None:
            self._writer.close()
        self._reader = self._writer = None
        self._backoff.dropped()

    def _close_silent(self) -> None:
        """The peer stayed silent ``reconnect_after_timeouts`` times in a row: close, so the
        next command opens a fresh connection (no back-off delay: the timeouts already
        paced the attempts; failed connects back off)."""
        self.frames.note(f"{self.attempts.in_row} silent attempts in a row; connection closed")
        if self._writer is not None:
            self._writer.close()
        self._reader = self._writer = None
        self.attempts.reset()

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
        async with self._lock:
            await self._ensure_connected()
            for attempt, timeout_s in enumerate(self.attempts.timeouts_s()):
                try:
                    code, data = await self._attempt(command, timeout_s)
                except TimeoutError as exc:
                    self.frames.note(f"{command}: no reply within {timeout_s} s")
                    action = self.attempts.silent(attempt)
                    if action == "retry":
                        continue
                    if action == "reopen":
                        self._close_silent()
                    text = f"{command}: {self.attempts.failure_text(attempt)}"
                    raise RobotTimeout(self.name, text, self.frames.snapshot()) from exc
                self.attempts.replied(attempt)
                if code != 0:
                    raise RobotProtocolError(
                        self.name,
                        f"{command}: controller error {code}: {data}",
                        self.frames.snapshot(),
                        code=code,
                    )
                return data
        raise AssertionError("unreachable: the last attempt returns or raises")

    async def _attempt(self, command: str, timeout_s: float) -> tuple[int, str]:
        """One request with a fresh sequence number; ``(error code, data)`` of its reply.

        Raises :class:`TimeoutError` when no reply comes within ``timeout_s`` (its late
        reply, if any, is discarded by a later attempt: its number is older). Raises
        :class:`RobotLinkDown` / :class:`RobotProtocolError` (connection closed) on a lost
        link or a frame that cannot be attributed.
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
                frame = await asyncio.wait_for(self._reader.readuntil(TERMINATOR), remaining)
                self.frames.add("rx", frame)
                try:
                    r_seq, code, data = decode_reply(frame)
                except (ValueError, UnicodeDecodeError) as exc:
                    self._drop("malformed frame; connection reset to re-synchronise")
                    raise RobotProtocolError(self.name, str(exc), self.frames.snapshot()) from exc
                if r_seq == -1:
                    self.alarms.append(Alarm(code, data, time.monotonic()))
                elif r_seq == seq:
                    return code, data
                elif r_seq < seq:
                    self.frames.note(f"late reply to i:{r_seq} discarded")
                else:
                    self._drop(f"reply i:{r_seq} newer than any request; connection reset")
                    raise RobotProtocolError(
                        self.name,
                        f"{command}: reply i:{r_seq} is newer than the request sent (i:{seq})",
                        self.frames.snapshot(),
                    )
        except TimeoutError:
            raise  # a subclass of OSError, but the link may well be up: the caller retries
        except (OSError, asyncio.IncompleteReadError, asyncio.LimitOverrunError) as exc:
            self._drop(f"link lost: {exc!r}")
            raise RobotLinkDown(self.name, f"link lost: {exc!r}", self.frames.snapshot()) from exc

    async def read_joints(self) -> JointReading:
        """``mot.getJntData(0)`` → :class:`JointReading` (first 6 values)."""
        data = await self.command(self.config.joints_command)
        try:
            values = parse_float_list(data)
        except ValueError as exc:
            raise RobotProtocolError(self.name, str(exc), self.frames.snapshot()) from exc
        if len(values) < 6:
            raise RobotProtocolError(
                self.name, f"{len(values)} joint values, expected 6", self.frames.snapshot()
            )
        return self._stale.check(joint_reading(values[:6], self.name))

    async def read_location(self) -> tuple[float, ...]:
        """``mot.getLocData(0)`` → X, Y, Z [mm], A, B, C [deg] of the TCP."""
        data = await self.command("mot.getLocData(0)")
        try:
            values = parse_float_list(data)
        except ValueError as exc:
            raise RobotProtocolError(self.name, str(exc), self.frames.snapshot()) from exc
        if len(values) < 6:
            raise RobotProtocolError(self.name, "location needs 6 values", self.frames.snapshot())
        return tuple(values[:6])
