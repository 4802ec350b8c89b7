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
abandoned attempt is never returned. The per-attempt wait is our ``asyncio.timeout``;
pymodbus' timeout is set longer so that its disconnect-after-N-timeouts rule never fires.
"""

from __future__ import annotations

import asyncio
import math
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field
from pymodbus.client import AsyncModbusTcpClient
from pymodbus.exceptions import ModbusException
from pymodbus.framer import FramerType

from drivers.robot import JointReading, joint_reading
from drivers.robot_link import LinkConfig, LinkedRobot, LinkLost


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


class ModbusRobotConfig(LinkConfig):
    """Configuration of :class:`ModbusTcpRobot`; ``preset = "ur"`` uses :data:`UR_PRESET`. The
    link settings (timeouts, retries, back-off, ``max_unchanged_s``) are
    :class:`drivers.robot_link.LinkConfig`'s."""

    kind: Literal["modbus-tcp"] = "modbus-tcp"
    port: Annotated[int, Field(ge=1, le=65535)] = 502
    device_id: Annotated[int, Field(ge=0, le=255)] = 1
    preset: Literal["ur", "custom"] = "ur"
    registers: JointRegisterMap = UR_PRESET

    def register_map(self) -> JointRegisterMap:
        return UR_PRESET if self.preset == "ur" else self.registers


class ModbusTcpRobot(LinkedRobot):
    """Asyncio driver reading joint angles over Modbus TCP (pymodbus)."""

    def __init__(self, config: ModbusRobotConfig) -> None:
        super().__init__(config)
        self.config = config
        self._client: AsyncModbusTcpClient | None = None

    def _trace(self, sending: bool, data: bytes) -> bytes:
        self.frames.add("tx" if sending else "rx", data)
        return data

    def _is_open(self) -> bool:
        return self._client is not None and self._client.connected

    async def _open(self) -> None:
        cfg = self.config
        if self._client is not None:
            self._client.close()
        self._client = AsyncModbusTcpClient(
            cfg.host,
            port=cfg.port,
            framer=FramerType.SOCKET,
            # Our own per-attempt wait (asyncio.timeout) always ends first, so pymodbus'
            # timeout and its "no response N times: disconnect" rule never fire.
            timeout=2 * cfg.timeout_s,
            retries=0,
            reconnect_delay=0,
            trace_packet=self._trace,
        )
        if not await self._client.connect() or not self._client.connected:
            raise LinkLost("connection refused or closed")

    async def _close(self) -> None:
        if self._client is not None:
            self._client.close()
            self._client = None

    async def _read(self, address: int, count: int, timeout_s: float) -> list[int]:
        """One attempt: ``count`` registers from ``address`` (a new pymodbus request, so a
        new transaction id; see the module docstring)."""
        try:
            async with asyncio.timeout(timeout_s):
                response: Any = await self._request(address, count)
        except ModbusException as exc:
            if not self._is_open():
                raise LinkLost(str(exc)) from exc
            raise TimeoutError from exc
        if response.isError():
            code = getattr(response, "exception_code", None)
            raise self.protocol_error(f"Modbus exception code {code or '?'}", code)
        regs = list(response.registers)
        if len(regs) != count:
            raise self.protocol_error(f"{len(regs)} registers, expected {count}")
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

    async def _request_joints(self, timeout_s: float) -> list[float]:
        """The angles and revolution counters in one request when they fit (one consistent
        snapshot); else three requests (see the module docstring)."""
        regmap = self.config.register_map()
        a, r = regmap.angle_address, regmap.revolution_address
        if r is None:
            return decode_joints_deg(await self._read(a, 6, timeout_s), None, regmap)
        if max(a, r) + 6 - min(a, r) <= 125:
            start = min(a, r)
            block = await self._read(start, max(a, r) + 6 - start, timeout_s)
            angles, revs = block[a - start : a - start + 6], block[r - start : r - start + 6]
            return decode_joints_deg(angles, revs, regmap)
        raise AssertionError("split reads are done by read_joints")

    async def read_joints(self) -> JointReading:
        """Current joint angles.

        Raises
        ------
        RobotLinkDown, RobotTimeout, RobotProtocolError
        """
        regmap = self.config.register_map()
        a, r = regmap.angle_address, regmap.revolution_address
        if r is None or max(a, r) + 6 - min(a, r) <= 125:
            return await super().read_joints()
        # Counters before and after the angles, each read under the link policy; repeated
        # when a counter changed in between (a wrap), so no value is off by a turn.
        for _ in range(3):
            revs = await self.call(lambda t: self._read(r, 6, t), "revolutions")
            angles = await self.call(lambda t: self._read(a, 6, t), "angles")
            if await self.call(lambda t: self._read(r, 6, t), "revolutions") == revs:
                values = decode_joints_deg(angles, revs, regmap)
                return self._stale.check(joint_reading(values, self.name))
        raise self.protocol_error("revolution counters kept changing")
