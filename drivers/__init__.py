"""Device drivers: the HY9648 cable-length indicator and robot joint-angle sources.

Drivers know nothing of the database or the service. Build them from configuration
mappings with :func:`make_indicator` and :func:`make_robot`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, NamedTuple, Protocol, runtime_checkable

from pydantic import BaseModel

from drivers.abb_rws import AbbRwsConfig, AbbRwsRobot
from drivers.ascii_indicator import AsciiIndicator, AsciiIndicatorConfig
from drivers.errors import (
    DeviceError,
    DeviceLinkDown,
    DeviceProtocolError,
    DeviceTimeout,
    IndicatorCRCError,
    IndicatorError,
    IndicatorLinkDown,
    IndicatorNoReply,
    IndicatorOverRange,
    IndicatorProtocolError,
    IndicatorTimeout,
    RobotError,
    RobotLinkDown,
    RobotNoData,
    RobotProtocolError,
    RobotStale,
    RobotTimeout,
)
from drivers.fanuc_rmi import FanucRmiConfig, FanucRmiRobot
from drivers.huashu import HuashuConfig, HuashuSocketCmdRobot
from drivers.indicator import IndicatorConfig, IndicatorReading, ModbusIndicator, RegisterMap
from drivers.kuka_varproxy import KukaVarProxyConfig, KukaVarProxyRobot
from drivers.modbus_robot import JointRegisterMap, ModbusRobotConfig, ModbusTcpRobot
from drivers.robot import JointReading, ManualRobot, ManualRobotConfig, RobotDriver
from drivers.ur_rtde import UrRtdeConfig, UrRtdeRobot


@runtime_checkable
class IndicatorDriver(Protocol):
    """What the daemon needs from a length indicator."""

    name: str

    async def connect(self) -> None:
        """Open the port now (otherwise the first :meth:`read` does)."""

    async def read(self) -> IndicatorReading:
        """One reading; raises :class:`IndicatorError` subclasses."""
        ...

    async def zero(self) -> None:
        """Zero the meter with its configured strategy."""

    async def close(self) -> None:
        """Close the port."""


def make_indicator(
    config: Mapping[str, Any] | IndicatorConfig | AsciiIndicatorConfig,
) -> ModbusIndicator | AsciiIndicator:
    """Indicator driver from a mapping; ``kind`` is ``modbus-rtu`` (default),
    ``modbus-tcp`` or ``ascii``. Raises ``pydantic.ValidationError`` on bad settings."""
    if isinstance(config, IndicatorConfig):
        return ModbusIndicator(config)
    if isinstance(config, AsciiIndicatorConfig):
        return AsciiIndicator(config)
    if config.get("kind", "modbus-rtu") == "ascii":
        return AsciiIndicator(AsciiIndicatorConfig.model_validate(dict(config)))
    return ModbusIndicator(IndicatorConfig.model_validate(dict(config)))


class RobotKind(NamedTuple):
    """One entry of :data:`ROBOT_KINDS`: the pydantic config model (its ``kind`` field is a
    ``Literal`` of the key) and the driver class built from it."""

    config: type[BaseModel]
    driver: Callable[[Any], RobotDriver]


#: Robot driver by ``[robot] kind``: adding a kind is one entry here. ``make_robot``, the
#: daemon's ``[robot]`` settings and ``cablecal serve --robot-kind`` read this table.
ROBOT_KINDS: dict[str, RobotKind] = {
    "manual": RobotKind(ManualRobotConfig, ManualRobot),
    "huashu-socketcmd": RobotKind(HuashuConfig, HuashuSocketCmdRobot),
    "modbus-tcp": RobotKind(ModbusRobotConfig, ModbusTcpRobot),
    "ur-rtde": RobotKind(UrRtdeConfig, UrRtdeRobot),
    "abb-rws": RobotKind(AbbRwsConfig, AbbRwsRobot),
    "kuka-varproxy": RobotKind(KukaVarProxyConfig, KukaVarProxyRobot),
    "fanuc-rmi": RobotKind(FanucRmiConfig, FanucRmiRobot),
}


def make_robot(config: Mapping[str, Any] | BaseModel) -> RobotDriver:
    """Robot driver from a config model or a mapping with ``kind`` (a key of
    :data:`ROBOT_KINDS`). Raises ``ValueError`` for another kind and
    ``pydantic.ValidationError`` for bad settings."""
    if isinstance(config, BaseModel):
        for entry in ROBOT_KINDS.values():
            if type(config) is entry.config:
                return entry.driver(config)
        raise ValueError(f"robot: no driver for config {type(config).__name__}")
    kind = config.get("kind")
    found = ROBOT_KINDS.get(str(kind))
    if found is None:
        raise ValueError(f"kind: unknown robot driver {kind!r}; use {', '.join(ROBOT_KINDS)}")
    return found.driver(found.config.model_validate(dict(config)))


__all__ = [
    "ROBOT_KINDS",
    "AbbRwsConfig",
    "AbbRwsRobot",
    "AsciiIndicator",
    "AsciiIndicatorConfig",
    "DeviceError",
    "DeviceLinkDown",
    "DeviceProtocolError",
    "DeviceTimeout",
    "HuashuConfig",
    "HuashuSocketCmdRobot",
    "IndicatorCRCError",
    "IndicatorConfig",
    "IndicatorDriver",
    "IndicatorError",
    "IndicatorLinkDown",
    "IndicatorNoReply",
    "IndicatorOverRange",
    "IndicatorProtocolError",
    "IndicatorReading",
    "IndicatorTimeout",
    "JointReading",
    "JointRegisterMap",
    "ManualRobot",
    "ManualRobotConfig",
    "ModbusIndicator",
    "ModbusRobotConfig",
    "ModbusTcpRobot",
    "RegisterMap",
    "RobotDriver",
    "RobotError",
    "RobotKind",
    "RobotLinkDown",
    "RobotNoData",
    "RobotProtocolError",
    "RobotStale",
    "RobotTimeout",
    "UrRtdeConfig",
    "UrRtdeRobot",
    "make_indicator",
    "make_robot",
]
