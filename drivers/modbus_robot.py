"""Joint angles from a Modbus TCP server: a generic holding-register map, with a Universal
Robots preset (angles 270–275 in mrad, unsigned, plus revolution counters 320–325:
``q = reg/1000 + int16(rev)·2π``, design note §2).

Angles and revolution counters are read in one request when they fit (one consistent
snapshot); otherwise counters are read before and after the angles and the read is repeated
if they changed, so a wrap between two requests never yields a value off by a turn.

Lossy links (issue 11): a request whose reply does not come within its timeout is re-sent at
once on the same connection (``retries``); the connection is closed and re-opened only after
``reconnect_after_timeouts`` silent attempts in a row. Every attempt is a new pymodbus request
with its own MBAP transaction id (pymodbus' own ``retries`` would re-send the *same* id, so a
late reply to the first send would be taken for the retry's; we keep them at 0). pymodbus
skips a frame whose transaction id is not the pending request's, so a late reply to an
abandoned attempt is never returned. The per-attempt wait is our ``asyncio.wait_for``;
pymodbus' timeout is set longer so that its disconnect-after-N-timeouts rule never fires.
"""

from __future__ import annotations

import asyncio
import math
import time
from typing import Annotated, Any, Literal, NoReturn

from pydantic import BaseModel, ConfigDict, Field
from pymodbus.client import AsyncModbusTcpClient
from pymodbus.exceptions import ModbusException
from pymodbus.framer import FramerType

from drivers.backoff import ReconnectBackoff, SilentAttempts
from drivers.errors import RobotLinkDown, RobotProtocolError, RobotTimeout
from drivers.frames import FrameLog
from drivers.robot import JointReading, StaleGuard, joint_reading


class JointRegisterMap(BaseModel):
    """Where and how joint angles are stored.

    ``q = raw / scale`` in ``unit``, with ``raw`` int16 when ``signed`` else uint16; when
    ``revolution_address`` is set, ``q += int16(rev) * (2π rad or 360 deg)``.
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    angle_address: Annotated[int, Field(ge=0, le=0xFFFF)] = 270
    scale: Annotated[float, Field(gt=0)] = 1000.0
    unit: Literal["rad", "deg"] = "rad"
    signed: bool = False
    revolution_address: Annotated[int | None, Field(ge=0, le=0xFFFF)] = 320
    read_function: Literal[3, 4] = 3


#: Universal Robots' Modbus server layout.
UR_PRESET = JointRegisterMap()


def decode_joints_deg(
    angles: list[int], revs: list[int] | None, regmap: JointRegisterMap
) -> list[float]:
    """Registers → 6 joint angles [deg]."""
    full_turn = 2 * math.pi if regmap.unit == "rad" else 360.0
    out = []
    for j in range(6):
        raw = angles[j]
        if regmap.signed and raw >= 0x8000:
            raw -= 0x10000
        q = raw / regmap.scale
        if revs is not None:
            rev = revs[j] - 0x10000 if revs[j] >= 0x8000 else revs[j]
            q += rev * full_turn
        out.append(math.degrees(q) if regmap.unit == "rad" else q)
    return out


class ModbusRobotConfig(BaseModel):
    """Configuration of :class:`ModbusTcpRobot`; ``preset = "ur"`` uses :data:`UR_PRESET`.

    ``timeout_s`` bounds the TCP connect and the last attempt's wait for a reply [s];
    ``fast_reply_timeout_s`` the wait of every earlier attempt (capped at ``timeout_s``) [s];
    ``retries`` immediate re-sends on the same connection after a silent attempt [count];
    ``reconnect_after_timeouts`` silent attempts in a row (across reads) after which the
    connection is closed and re-opened [count]. See :class:`drivers.backoff.SilentAttempts`.
    """

    model_config = ConfigDict(extra="forbid")

    kind: Literal["modbus-tcp"] = "modbus-tcp"
    name: str = "robot"
    host: str = "127.0.0.1"
    port: Annotated[int, Field(ge=1, le=65535)] = 502
    device_id: Annotated[int, Field(ge=0, le=255)] = 1
    preset: Literal["ur", "custom"] = "ur"
    registers: JointRegisterMap = UR_PRESET
    timeout_s: Annotated[float, Field(gt=0)] = 1.0
    fast_reply_timeout_s: Annotated[float, Field(gt=0)] = 0.2
    retries: Annotated[int, Field(ge=0)] = 2
    reconnect_after_timeouts: Annotated[int, Field(ge=1)] = 3
    reconnect_min_s: Annotated[float, Field(gt=0)] = 0.1
    reconnect_max_s: Annotated[float, Field(gt=0)] = 1.0
    max_unchanged_s: Annotated[float | None, Field(gt=0)] = None
    frame_log_size: Annotated[int, Field(ge=1)] = 16

    def register_map(self) -> JointRegisterMap:
        return UR_PRESET if self.preset == "ur" else self.registers


class ModbusTcpRobot:
    """Asyncio driver reading joint angles over Modbus TCP (pymodbus)."""

    def __init__(self, config: ModbusRobotConfig) -> None:
        self.config = config
        self.name = config.name
        self.frames = FrameLog(config.frame_log_size)
        self._client: AsyncModbusTcpClient | None = None
        self._backoff = ReconnectBackoff(config.reconnect_min_s, config.reconnect_max_s)
        self._stale = StaleGuard(config.name, config.max_unchanged_s)
        #: Successful TCP connects since creation [count] (the first one included).
        self.connects = 0
        #: Retry policy and its counters (silent attempts, reads saved by a retry).
        self.attempts = SilentAttempts(
            config.retries,
            config.reconnect_after_timeouts,
            min(config.fast_reply_timeout_s, config.timeout_s),
            config.timeout_s,
        )

    def _trace(self, sending: bool, data: bytes) -> bytes:
        self.frames.add("tx" if sending else "rx", data)
        return data

    @property
    def connected(self) -> bool:
        return self._client is not None and self._client.connected

    async def connect(self) -> None:
        """Open the connection now. Raises :class:`RobotLinkDown`."""
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
        if self._client is not None:
            self._client.close()
        self._client = AsyncModbusTcpClient(
            cfg.host,
            port=cfg.port,
            framer=FramerType.SOCKET,
            # Our own per-attempt wait (asyncio.wait_for) always ends first, so pymodbus'
            # timeout and its "no response N times: disconnect" rule never fire.
            timeout=2 * cfg.timeout_s,
            retries=0,
            reconnect_delay=0,
            trace_packet=self._trace,
        )
        try:
            opened = await asyncio.wait_for(self._client.connect(), cfg.timeout_s)
        except TimeoutError:
            opened = False
        if not opened or not self._client.connected:
            self._client.close()
            self._client = None
            self._backoff.failed()
            self.frames.note(f"connect {cfg.host}:{cfg.port} failed")
            raise RobotLinkDown(
                self.name, f"cannot connect to {cfg.host}:{cfg.port}", self.frames.snapshot()
            )
        self._backoff.succeeded()
        self.connects += 1
        self.attempts.reset()
        self.frames.note(f"connected {cfg.host}:{cfg.port}")

    async def close(self) -> None:
        """Close the connection."""
        if self._client is not None:
            self._client.close()
            self._client = None

    async def _read(self, address: int, count: int) -> list[int]:
        """``count`` registers from ``address``; a silent attempt is retried at once with a
        new transaction id (see the module docstring).

        Raises
        ------
        RobotLinkDown, RobotTimeout, RobotProtocolError
        """
        await self._ensure_connected()
        response: Any = None
        for attempt, timeout_s in enumerate(self.attempts.timeouts_s()):
            try:
                response = await asyncio.wait_for(self._request(address, count), timeout_s)
            except (TimeoutError, ModbusException) as exc:
                if isinstance(exc, ModbusException) and not self.connected:
                    self._lost(exc)
                self.frames.note(f"no reply within {timeout_s} s (attempt {attempt + 1})")
                action = self.attempts.silent(attempt)
                if action == "retry":
                    continue
                if action == "reopen":
                    self._close_silent()
                text = self.attempts.failure_text(attempt)
                raise RobotTimeout(self.name, text, self.frames.snapshot()) from exc
            self.attempts.replied(attempt)
            break
        if response.isError():
            raise RobotProtocolError(
                self.name,
                f"Modbus exception code {getattr(response, 'exception_code', '?')}",
                self.frames.snapshot(),
                code=getattr(response, "exception_code", None),
            )
        regs = list(response.registers)
        if len(regs) != count:
            raise RobotProtocolError(
                self.name, f"{len(regs)} registers, expected {count}", self.frames.snapshot()
            )
        return regs

    async def _request(self, address: int, count: int) -> Any:
        """One read request (pymodbus gives it the next transaction id)."""
        assert self._client is not None
        device_id = self.config.device_id
        if self.config.register_map().read_function == 4:
            return await self._client.read_input_registers(
                address, count=count, device_id=device_id
            )
        return await self._client.read_holding_registers(address, count=count, device_id=device_id)

    def _lost(self, exc: Exception) -> NoReturn:
        """The connection went away during a request: close, back off, raise."""
        if self._client is not None:
            self._client.close()
            self._client = None
        self._backoff.defer(self.config.reconnect_min_s)
        raise RobotLinkDown(self.name, f"link lost: {exc}", self.frames.snapshot()) from exc

    def _close_silent(self) -> None:
        """``reconnect_after_timeouts`` silent attempts in a row: close, so the next read
        opens a fresh connection (no back-off delay: the timeouts already paced the
        attempts; failed connects back off)."""
        self.frames.note(f"{self.attempts.in_row} silent attempts in a row; connection closed")
        if self._client is not None:
            self._client.close()
            self._client = None
        self.attempts.reset()

    async def read_joints(self) -> JointReading:
        """Current joint angles.

        Raises
        ------
        RobotLinkDown, RobotTimeout, RobotProtocolError
        """
        regmap = self.config.register_map()
        a, r = regmap.angle_address, regmap.revolution_address
        if r is None:
            angles, revs = await self._read(a, 6), None
        elif max(a, r) + 6 - min(a, r) <= 125:
            start = min(a, r)
            block = await self._read(start, max(a, r) + 6 - start)
            angles, revs = block[a - start : a - start + 6], block[r - start : r - start + 6]
        else:
            for _ in range(3):
                revs = await self._read(r, 6)
                angles = await self._read(a, 6)
                if await self._read(r, 6) == revs:
                    break
            else:
                raise RobotProtocolError(
                    self.name, "revolution counters kept changing", self.frames.snapshot()
                )
        values = decode_joints_deg(angles, revs, regmap)
        return self._stale.check(joint_reading(values, self.name))
