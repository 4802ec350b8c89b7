"""Universal Robots, Real-Time Data Exchange (RTDE, protocol version 2, TCP port 30004):
``actual_q`` [rad] → joint angles [deg].

Why this protocol is written here and not taken from ``ur_rtde`` (SDU Robotics' client, well
maintained, pip ``ur-rtde``): it is a blocking C++ client that reads on its own thread, and
its Python binding keeps the GIL while it blocks (connecting, or waiting for the controller's
setup replies): called from a worker thread it still stops the daemon's asyncio loop, and a
controller that accepts the connection but never answers would stop the sampler, the REST
API and the watchdog for as long as its internal timeout. It cannot be cancelled from
asyncio, and ``getActualQ()`` returns the last value received however old it is (no age).
The part of RTDE needed to read joints is small (five package types, two fixed-size fields),
so it is done here on asyncio, under the shared link policy (:mod:`drivers.robot_link`).
The cross-check test reads the emulated controller with ur_rtde's ``RTDEReceiveInterface``
(in a subprocess) so the two implementations are held to the same wire.

The session: connect, ``V`` protocol version 2, ``v`` controller version, ``O`` output
recipe ``timestamp,actual_q`` at ``frequency_hz``, ``S`` start; then the controller streams
``U`` data packages, which a reader task keeps (the latest one, with its arrival time).

A read (:meth:`UrRtdeRobot.read_joints`) waits for a data package *generated after the read
began*, so no value older than the request is ever returned: the package's controller
``timestamp`` is mapped to the local clock by the smallest arrival-minus-timestamp offset
seen on this connection (the least-delayed package), and a package whose generation precedes
the read by more than one stream period is skipped (a package held back by a congested link
arrives late with old data). No fresh package within the attempt's timeout is a silent
attempt (retried; the connection is re-opened after ``reconnect_after_timeouts`` in a row).
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import struct
import time
from typing import Annotated, Literal

from pydantic import Field

from drivers.robot_link import LinkConfig, LinkedRobot, LinkLost

# RTDE package types.
REQUEST_PROTOCOL_VERSION = ord("V")
GET_URCONTROL_VERSION = ord("v")
TEXT_MESSAGE = ord("M")
DATA_PACKAGE = ord("U")
SETUP_OUTPUTS = ord("O")
START = ord("S")
PAUSE = ord("P")

PROTOCOL_VERSION = 2
#: The variables read, and the types the controller must confirm.
VARIABLES = ("timestamp", "actual_q")
TYPES = ("DOUBLE", "VECTOR6D")
#: Largest package accepted from the controller [bytes].
MAX_PACKAGE_BYTES = 65535


def rtde_package(kind: int, payload: bytes = b"") -> bytes:
    """``uint16 size`` (header included) + ``uint8 type`` + payload, big-endian."""
    return struct.pack(">HB", 3 + len(payload), kind) + payload


class UrRtdeConfig(LinkConfig):
    """Configuration of :class:`UrRtdeRobot`; the link settings (timeouts, retries,
    back-off, ``max_unchanged_s``) are :class:`drivers.robot_link.LinkConfig`'s.

    ``frequency_hz``: rate of the controller's data packages [Hz] (CB3: up to 125, e-Series:
    up to 500; the driver needs only a few per read, so the default spares the link).
    """

    kind: Literal["ur-rtde"] = "ur-rtde"
    port: Annotated[int, Field(ge=1, le=65535)] = 30004
    frequency_hz: Annotated[float, Field(ge=1, le=500)] = 125.0


class UrRtdeRobot(LinkedRobot):
    """Asyncio RTDE reader of ``actual_q`` (see the module docstring)."""

    #: The robot maker whose controller this driver reads (the robot library's words).
    MAKER = "ur"

    def __init__(self, config: UrRtdeConfig) -> None:
        super().__init__(config)
        self.config = config
        self.joints_what = "actual_q"
        self._reader: asyncio.StreamReader | None = None
        self._writer: asyncio.StreamWriter | None = None
        self._task: asyncio.Task[None] | None = None
        self._recipe_id = 0
        #: ``(major, minor, bugfix, build)`` of the connected controller.
        self.controller_version: tuple[int, ...] | None = None
        self._latest: tuple[float, float, tuple[float, ...]] | None = None  # t_ctrl, t_gen, q
        self._offset_s = math.inf
        self._fresh = asyncio.Condition()
        self._lost: str | None = None
        #: Data packages that arrived more than two stream periods after they were generated
        #: (held back by the link or the controller) [count]; never returned as fresh.
        self.late_packages = 0

    def _is_open(self) -> bool:
        return (
            self._writer is not None
            and not self._writer.is_closing()
            and self._task is not None
            and not self._task.done()
        )

    # ------------------------------------------------------------------ session
    async def _open(self) -> None:
        cfg = self.config
        self._reader, self._writer = await asyncio.open_connection(cfg.host, cfg.port)
        self._latest, self._offset_s, self._lost = None, math.inf, None
        accepted = await self._ask(
            REQUEST_PROTOCOL_VERSION, struct.pack(">H", PROTOCOL_VERSION), ">B"
        )
        if accepted != (1,):
            raise LinkLost(f"controller refused RTDE protocol version {PROTOCOL_VERSION}")
        self.controller_version = await self._ask(GET_URCONTROL_VERSION, b"", ">IIII")
        payload = struct.pack(">d", cfg.frequency_hz) + ",".join(VARIABLES).encode()
        reply = await self._request(SETUP_OUTPUTS, payload)
        self._recipe_id = reply[0] if reply else 0
        types = tuple(reply[1:].decode("ascii", errors="replace").split(","))
        if types != TYPES or self._recipe_id == 0:
            raise LinkLost(
                f"output recipe {','.join(VARIABLES)} refused: types {','.join(types)} "
                f"(recipe id {self._recipe_id})"
            )
        if await self._ask(START, b"", ">B") != (1,):
            raise LinkLost("controller refused to start the data stream")
        self._task = asyncio.ensure_future(self._receive())

    async def _request(self, kind: int, payload: bytes) -> bytes:
        """Send a control package, return the payload of its reply (same type); text
        messages in between are logged."""
        assert self._writer is not None
        data = rtde_package(kind, payload)
        self.frames.add("tx", data)
        self._writer.write(data)
        await self._writer.drain()
        while True:
            r_kind, r_payload = await self._package()
            if r_kind == kind:
                return r_payload
            if r_kind == TEXT_MESSAGE:
                self.frames.note(f"controller message: {_text(r_payload)}")
            elif r_kind != DATA_PACKAGE:
                raise LinkLost(f"unexpected RTDE package {chr(r_kind)!r} during set-up")

    async def _ask(self, kind: int, payload: bytes, fmt: str) -> tuple[int, ...]:
        reply = await self._request(kind, payload)
        if len(reply) != struct.calcsize(fmt):
            raise LinkLost(f"RTDE reply {chr(kind)!r} of {len(reply)} bytes")
        return tuple(struct.unpack(fmt, reply))

    async def _package(self) -> tuple[int, bytes]:
        assert self._reader is not None
        try:
            head = await self._reader.readexactly(3)
            size, kind = struct.unpack(">HB", head)
            if size < 3:
                raise LinkLost(f"RTDE package size {size}")
            payload = await self._reader.readexactly(size - 3)
        except (OSError, asyncio.IncompleteReadError) as exc:
            raise LinkLost(repr(exc)) from exc
        if kind != DATA_PACKAGE:
            self.frames.add("rx", head + payload)
        return kind, payload

    async def _receive(self) -> None:
        """Reader task: keep the latest data package of our recipe."""
        fmt = ">Bd6d"
        try:
            while True:
                kind, payload = await self._package()
                if kind == TEXT_MESSAGE:
                    self.frames.note(f"controller message: {_text(payload)}")
                    continue
                if kind != DATA_PACKAGE or len(payload) != struct.calcsize(fmt):
                    continue
                recipe_id, t_ctrl, *q_rad = struct.unpack(fmt, payload)
                if recipe_id != self._recipe_id:
                    continue
                now = time.monotonic()
                self._offset_s = min(self._offset_s, now - t_ctrl)
                t_gen = t_ctrl + self._offset_s
                if now - t_gen > 2.0 / self.config.frequency_hz:
                    self.late_packages += 1
                self._latest = (t_ctrl, t_gen, tuple(q_rad))
                async with self._fresh:
                    self._fresh.notify_all()
        except LinkLost as exc:
            self._lost = str(exc)
            self.frames.note(f"stream ended: {exc}")
            async with self._fresh:
                self._fresh.notify_all()

    async def _close(self) -> None:
        task, self._task = self._task, None
        if task is not None:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task
        writer, self._reader, self._writer = self._writer, None, None
        if writer is not None:
            writer.close()
            with contextlib.suppress(Exception):
                await writer.wait_closed()

    # ------------------------------------------------------------------ reads
    async def _request_joints(self, timeout_s: float) -> list[float]:
        """The first data package generated after this call began (see the module
        docstring); ``actual_q`` in degrees."""
        t_asked = time.monotonic()
        oldest_s = t_asked - 1.0 / self.config.frequency_hz
        deadline = t_asked + timeout_s

        def fresh() -> bool:
            return self._lost is not None or (
                self._latest is not None and self._latest[1] >= oldest_s
            )

        async with self._fresh:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise TimeoutError
            async with asyncio.timeout(remaining):
                await self._fresh.wait_for(fresh)
        if self._lost is not None:
            raise LinkLost(self._lost)
        assert self._latest is not None
        return [math.degrees(v) for v in self._latest[2]]


def _text(payload: bytes) -> str:
    """A version-2 text message: ``uint8`` length + message, source, ``uint8`` level."""
    if not payload:
        return ""
    n = payload[0]
    return payload[1 : 1 + n].decode("utf-8", errors="replace")


__all__ = ["PAUSE", "UrRtdeConfig", "UrRtdeRobot", "rtde_package"]
