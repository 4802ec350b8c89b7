"""The one link policy of every networked robot driver: retry, back-off, stale and frozen
joints, reconnect after a link-down.

A driver subclasses :class:`LinkedRobot` and writes three things:

``_open()``
    Open the connection (a socket, an HTTP client, a session). Bounded by ``timeout_s`` here.
``_request_joints(timeout_s)``
    One request → six joint angles [deg]. Raise :class:`TimeoutError` when no reply came
    within ``timeout_s`` (the caller retries), :class:`LinkLost` when the connection went away,
    :class:`Unattributable` for a reply that cannot be matched to the request (the connection
    is reset so the stream re-synchronises), :class:`~drivers.errors.RobotProtocolError` for
    a reply that arrived but is an error or malformed (the peer is alive: no reset).
``_close()``
    Close the connection; must not raise.

plus ``_is_open()``. A driver over one TCP stream subclasses :class:`StreamLinkedRobot`,
which opens, tells and closes that stream. Everything else is here, the same for every brand:

- **Retries** (:class:`drivers.backoff.SilentAttempts`): a silent attempt is retried at once
  on the same connection with a short wait (``fast_reply_timeout_s``); the last attempt waits
  ``timeout_s``; after ``reconnect_after_timeouts`` silent attempts in a row (across reads)
  the connection is closed and the next read opens a fresh one. Each attempt must be a new
  request the driver can tell apart from the earlier ones (sequence number, transaction id,
  or a new HTTP request on a connection the cancelled one did not reuse): a late reply to an
  abandoned attempt is never returned.
- **Back-off** (:class:`drivers.backoff.ReconnectBackoff`): a failed connect doubles the wait
  before the next one (``reconnect_min_s`` … ``reconnect_max_s``); reads in between fail at
  once with :class:`RobotLinkDown` naming the wait, so the sampler is never blocked by a dead
  controller. A lost link waits ``reconnect_min_s`` before reconnecting.
- **Validation**: six finite angles or :class:`RobotProtocolError`
  (:func:`drivers.robot.make_joints`); nothing else is returned.
- **Frozen joints** (:class:`drivers.robot.StaleGuard`): bit-identical joints for longer than
  ``max_unchanged_s`` raise :class:`RobotStale` (off by default: a robot at rest repeats).
- **Frame log** (:class:`drivers.wire_bytes.FrameLog`): every error carries the last frames.

The counters tests and benchmarks read: :attr:`LinkedRobot.connects` (successful connects)
and :attr:`LinkedRobot.attempts` (silent attempts, reads saved by a retry).
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from abc import ABC, abstractmethod
from collections.abc import Awaitable, Callable, Sequence
from typing import Annotated, TypeVar

from pydantic import BaseModel, ConfigDict, Field

from drivers.backoff import ReconnectBackoff, SilentAttempts
from drivers.errors import RobotLinkDown, RobotProtocolError, RobotTimeout
from drivers.robot import JointReading, StaleGuard, joint_reading
from drivers.wire_bytes import FrameLog

T = TypeVar("T")


class LinkLost(Exception):
    """Raised by a driver's attempt: the connection went away during the request."""


class Unattributable(Exception):
    """Raised by a driver's attempt: a reply that answers no request sent, or cannot be
    parsed as a frame at all; the connection is reset so the stream re-synchronises."""


class LinkConfig(BaseModel):
    """Settings every networked robot driver shares (its own config model adds ``kind``,
    its port default and protocol settings).

    ``timeout_s`` bounds the connect and the last attempt's wait for a reply [s];
    ``fast_reply_timeout_s`` the wait of every earlier attempt (capped at ``timeout_s``) [s];
    ``retries`` immediate re-sends on the same connection after a silent attempt [count];
    ``reconnect_after_timeouts`` silent attempts in a row (across reads) after which the
    connection is closed and re-opened [count]; ``reconnect_min_s`` / ``reconnect_max_s`` the
    back-off between failed connects [s]; ``max_unchanged_s`` raises :class:`RobotStale` when
    the joints stay bit-identical longer [s] (unset: off); ``frame_log_size`` frames kept for
    error reports [count].
    """

    model_config = ConfigDict(extra="forbid")

    name: str = "robot"
    host: str = "127.0.0.1"
    port: Annotated[int, Field(ge=1, le=65535)]
    timeout_s: Annotated[float, Field(gt=0)] = 1.0
    fast_reply_timeout_s: Annotated[float, Field(gt=0)] = 0.2
    retries: Annotated[int, Field(ge=0)] = 2
    reconnect_after_timeouts: Annotated[int, Field(ge=1)] = 3
    reconnect_min_s: Annotated[float, Field(gt=0)] = 0.1
    reconnect_max_s: Annotated[float, Field(gt=0)] = 1.0
    max_unchanged_s: Annotated[float | None, Field(gt=0)] = None
    frame_log_size: Annotated[int, Field(ge=1)] = 16


class LinkedRobot(ABC):
    """Base of the networked robot drivers (see the module docstring)."""

    def __init__(self, config: LinkConfig) -> None:
        self.link_config = config
        self.name = config.name
        self.frames = FrameLog(config.frame_log_size)
        self._backoff = ReconnectBackoff(config.reconnect_min_s, config.reconnect_max_s)
        self._stale = StaleGuard(config.name, config.max_unchanged_s)
        #: Retry policy and its counters (silent attempts, reads saved by a retry).
        self.attempts = SilentAttempts(
            config.retries,
            config.reconnect_after_timeouts,
            min(config.fast_reply_timeout_s, config.timeout_s),
            config.timeout_s,
        )
        #: Successful connects since creation [count] (the first one included).
        self.connects = 0
        #: What a joint read is called in messages (the command, the resource).
        self.joints_what = "joints"
        self._lock = asyncio.Lock()

    # ------------------------------------------------------------------ the driver's part
    @abstractmethod
    async def _open(self) -> None:
        """Open the connection (raise :class:`OSError`, :class:`TimeoutError` or
        :class:`LinkLost` when it cannot be opened)."""

    @abstractmethod
    async def _request_joints(self, timeout_s: float) -> Sequence[float]:
        """One request → six joint angles [deg] (see the module docstring for errors)."""

    @abstractmethod
    async def _close(self) -> None:
        """Close the connection (never raises)."""

    @abstractmethod
    def _is_open(self) -> bool:
        """Whether the connection is open."""

    # ------------------------------------------------------------------ shared
    @property
    def endpoint(self) -> str:
        """``host:port`` for messages."""
        return f"{self.link_config.host}:{self.link_config.port}"

    @property
    def connected(self) -> bool:
        return self._is_open()

    async def connect(self) -> None:
        """Open the connection now. Raises :class:`RobotLinkDown`."""
        async with self._lock:
            await self._ensure_connected(force=True)

    async def close(self) -> None:
        """Close the connection."""
        await self._close()

    async def read_joints(self) -> JointReading:
        """Current joint angles [deg].

        Raises
        ------
        RobotLinkDown, RobotTimeout, RobotProtocolError, RobotStale
        """
        values = await self.call(self._request_joints, self.joints_what)
        return self._stale.check(joint_reading(values, self.name))

    async def call(self, attempt: Callable[[float], Awaitable[T]], what: str) -> T:
        """Run ``attempt(timeout_s)`` under the link policy (connect when needed, retry a
        silent attempt, reset on a lost link or an unattributable reply); its result.

        Raises
        ------
        RobotLinkDown, RobotTimeout, RobotProtocolError
        """
        async with self._lock:
            await self._ensure_connected()
            for n, timeout_s in enumerate(self.attempts.timeouts_s()):
                try:
                    result = await attempt(timeout_s)
                except TimeoutError as exc:
                    self.frames.note(f"{what}: no reply within {timeout_s} s (attempt {n + 1})")
                    action = self.attempts.silent(n)
                    if action == "retry":
                        continue
                    if action == "reopen":
                        await self._close_silent()
                    text = f"{what}: {self.attempts.failure_text(n)}"
                    raise RobotTimeout(self.name, text, self.frames.snapshot()) from exc
                except LinkLost as exc:
                    await self._drop(f"link lost: {exc}")
                    raise RobotLinkDown(
                        self.name, f"link lost: {exc}", self.frames.snapshot()
                    ) from exc
                except Unattributable as exc:
                    await self._drop(f"{exc}; connection reset to re-synchronise")
                    raise RobotProtocolError(
                        self.name, f"{what}: {exc}", self.frames.snapshot()
                    ) from exc
                except RobotProtocolError:
                    self.attempts.replied(n)  # the peer answered: the link is alive
                    raise
                self.attempts.replied(n)
                return result
        raise AssertionError("unreachable: the last attempt returns or raises")

    def protocol_error(self, message: str, code: int | None = None) -> RobotProtocolError:
        """A :class:`RobotProtocolError` with the frame log (for the driver's attempts)."""
        return RobotProtocolError(self.name, message, self.frames.snapshot(), code=code)

    async def _ensure_connected(self, force: bool = False) -> None:
        if self._is_open():
            return
        wait_s = self._backoff.remaining_s(time.monotonic())
        if not force and wait_s > 0:
            raise RobotLinkDown(
                self.name,
                f"{self.endpoint} down; next reconnect in {wait_s:.2f} s",
                self.frames.snapshot(),
            )
        try:
            async with asyncio.timeout(self.link_config.timeout_s):
                await self._open()
        except (TimeoutError, OSError, LinkLost) as exc:
            await self._close()
            self._backoff.failed()
            why = str(exc) or type(exc).__name__
            self.frames.note(f"connect {self.endpoint} failed: {why}")
            raise RobotLinkDown(
                self.name, f"cannot connect to {self.endpoint}: {why}", self.frames.snapshot()
            ) from exc
        self._backoff.succeeded()
        self.connects += 1
        self.attempts.reset()
        self.frames.note(f"connected {self.endpoint}")

    async def _drop(self, why: str) -> None:
        """The link was lost (or must be reset): close, wait ``reconnect_min_s``."""
        self.frames.note(why)
        await self._close()
        self._backoff.dropped()

    async def _close_silent(self) -> None:
        """``reconnect_after_timeouts`` silent attempts in a row: close, so the next read
        opens a fresh connection (no back-off delay: the timeouts already paced the attempts;
        failed connects back off)."""
        self.frames.note(f"{self.attempts.in_row} silent attempts in a row; connection closed")
        await self._close()
        self.attempts.reset()


class StreamLinkedRobot(LinkedRobot):
    """A :class:`LinkedRobot` over one TCP stream (asyncio streams to ``host:port``): the
    opening, the state and the closing of the link, the same for every such driver, so a
    driver writes only ``_request_joints`` (and may extend ``_open``)."""

    def __init__(self, config: LinkConfig) -> None:
        super().__init__(config)
        self._reader: asyncio.StreamReader | None = None
        self._writer: asyncio.StreamWriter | None = None

    def _is_open(self) -> bool:
        return self._writer is not None and not self._writer.is_closing()

    async def _open(self) -> None:
        self._reader, self._writer = await asyncio.open_connection(
            self.link_config.host, self.link_config.port
        )

    async def _close(self) -> None:
        """Forget the streams first (a concurrent reader sees a closed link), then close the
        socket and wait for it; never raises."""
        writer, self._reader, self._writer = self._writer, None, None
        if writer is not None:
            writer.close()
            with contextlib.suppress(Exception):
                await writer.wait_closed()
