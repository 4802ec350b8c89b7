"""Device drivers: the HY9648 cable-length indicator and robot joint-angle sources.

Drivers know nothing of the database or the service. Build them from configuration
mappings with :func:`make_indicator` and :func:`make_robot`.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, Protocol, runtime_checkable

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
from drivers.huashu import HuashuConfig, HuashuSocketCmdRobot
from drivers.indicator import IndicatorConfig, IndicatorReading, ModbusIndicator, RegisterMap
from drivers.modbus_robot import JointRegisterMap, ModbusRobotConfig, ModbusTcpRobot
from drivers.robot import JointReading, ManualRobot, ManualRobotConfig, RobotDriver


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


def make_robot(
    config: Mapping[str, Any] | HuashuConfig | ModbusRobotConfig | ManualRobotConfig,
) -> HuashuSocketCmdRobot | ModbusTcpRobot | ManualRobot:
    """Robot driver from a mapping; ``kind`` is ``huashu-socketcmd``, ``modbus-tcp`` or
    ``manual``. Raises ``ValueError`` for another kind."""
    if isinstance(config, HuashuConfig):
        return HuashuSocketCmdRobot(config)
    if isinstance(config, ModbusRobotConfig):
        return ModbusTcpRobot(config)
    if isinstance(config, ManualRobotConfig):
        return ManualRobot(config)
    kind = config.get("kind")
    if kind == "huashu-socketcmd":
        return HuashuSocketCmdRobot(HuashuConfig.model_validate(dict(config)))
    if kind == "modbus-tcp":
        return ModbusTcpRobot(ModbusRobotConfig.model_validate(dict(config)))
    if kind == "manual":
        return ManualRobot(ManualRobotConfig.model_validate(dict(config)))
    raise ValueError(
        f"kind: unknown robot driver {kind!r}; use huashu-socketcmd, modbus-tcp, manual"
    )


__all__ = [
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
    "RobotLinkDown",
    "RobotNoData",
    "RobotProtocolError",
    "RobotStale",
    "RobotTimeout",
    "make_indicator",
    "make_robot",
]
