"""Configuration of the Modbus indicator driver: where the meter keeps its values
(:class:`RegisterMap`) and how to reach it (:class:`IndicatorConfig`).

The defaults are those of the design note ``hardware-protocols.md`` §1: value int32 at 0x0000
(ABCD), decimals at 0x0002, status bits at 0x0007, command register 0x0010 (1 = zero).
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

#: Largest register count of one FC03/FC04 request.
MAX_READ_COUNT = 125


class RegisterMap(BaseModel):
    """Where the indicator keeps its values. Defaults: the design note's map.

    Addresses are 0-based protocol addresses (``0x0000`` is holding register 40001).
    ``None`` means the meter has no such register.
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    value_address: Annotated[int, Field(ge=0, le=0xFFFE)] = 0x0000
    word_order: Literal["ABCD", "CDAB"] = "ABCD"
    decimals_address: Annotated[int | None, Field(ge=0, le=0xFFFF)] = 0x0002
    raw_count_address: Annotated[int | None, Field(ge=0, le=0xFFFE)] = 0x0003
    magnification_address: Annotated[int | None, Field(ge=0, le=0xFFFE)] = 0x0005
    status_address: Annotated[int | None, Field(ge=0, le=0xFFFF)] = 0x0007
    preset_address: Annotated[int | None, Field(ge=0, le=0xFFFE)] = 0x0008
    command_address: Annotated[int, Field(ge=0, le=0xFFFF)] = 0x0010
    zero_command: Annotated[int, Field(ge=0, le=0xFFFF)] = 1
    preset_command: Annotated[int, Field(ge=0, le=0xFFFF)] = 2
    zero_coil_address: Annotated[int, Field(ge=0, le=0xFFFF)] = 0x0000
    slave_address_register: Annotated[int, Field(ge=0, le=0xFFFF)] = 0x0020
    baud_code_register: Annotated[int, Field(ge=0, le=0xFFFF)] = 0x0021
    read_function: Literal[3, 4] = 3
    over_range_bit: Annotated[int, Field(ge=0, le=15)] = 0
    under_range_bit: Annotated[int, Field(ge=0, le=15)] = 1
    moving_bit: Annotated[int, Field(ge=0, le=15)] = 2

    def read_block(self, with_decimals: bool) -> tuple[int, int]:
        """``(start, count)`` of the single read covering value, decimals and status."""
        spans = [(self.value_address, 2)]
        if with_decimals and self.decimals_address is not None:
            spans.append((self.decimals_address, 1))
        if self.status_address is not None:
            spans.append((self.status_address, 1))
        start = min(a for a, _ in spans)
        end = max(a + n for a, n in spans)
        return start, end - start


class IndicatorConfig(BaseModel):
    """Configuration of a Modbus indicator.

    Attributes
    ----------
    kind : {"modbus-rtu", "modbus-tcp"}
        ``modbus-rtu``: RTU frames over ``port`` (serial device, pty, or ``socket://h:p``).
        ``modbus-tcp``: MBAP frames to ``host:tcp_port``.
    decimals : int or None
        Fixed decimal places; ``None`` reads them from ``registers.decimals_address``.
    zero_strategy : {"command", "write_zero", "coil", "none"}
        How :meth:`ModbusIndicator.zero` zeroes the meter (design note §1).
    timeout_s : float
        Per-attempt reply timeout.
    retries : int
        Extra attempts per :meth:`~ModbusIndicator.read` after a timeout or CRC error.
    quiet_s : float or None
        After a failed attempt, wait until no byte arrived for this long; default ``timeout_s``.
    over_range_policy : {"raise", "flag"}
        ``raise``: an over/under-range status raises :class:`IndicatorOverRange`;
        ``flag``: the reading is returned with ``over_range=True``.
    """

    model_config = ConfigDict(extra="forbid")

    kind: Literal["modbus-rtu", "modbus-tcp"] = "modbus-rtu"
    name: str = "indicator"
    port: str = "/dev/ttyUSB0"
    host: str = "127.0.0.1"
    tcp_port: Annotated[int, Field(ge=1, le=65535)] = 502
    baud: Annotated[int, Field(ge=300, le=921600)] = 9600
    parity: Literal["N", "E", "O"] = "N"
    stopbits: Literal[1, 2] = 1
    bytesize: Literal[7, 8] = 8
    device_id: Annotated[int, Field(ge=0, le=247)] = 1
    registers: RegisterMap = RegisterMap()
    decimals: Annotated[int | None, Field(ge=0, le=6)] = None
    zero_strategy: Literal["command", "write_zero", "coil", "none"] = "command"
    timeout_s: Annotated[float, Field(gt=0)] = 0.5
    retries: Annotated[int, Field(ge=0, le=10)] = 1
    quiet_s: Annotated[float | None, Field(ge=0)] = None
    reconnect_min_s: Annotated[float, Field(gt=0)] = 0.1
    reconnect_max_s: Annotated[float, Field(gt=0)] = 1.0
    over_range_policy: Literal["raise", "flag"] = "raise"
    frame_log_size: Annotated[int, Field(ge=1)] = 16

    @model_validator(mode="after")
    def _check(self) -> IndicatorConfig:
        if self.decimals is None and self.registers.decimals_address is None:
            raise ValueError("decimals: required when registers.decimals_address is None")
        _, count = self.registers.read_block(self.decimals is None)
        if count > MAX_READ_COUNT:
            raise ValueError(
                f"registers: value, decimals and status span {count} registers; "
                f"at most {MAX_READ_COUNT} fit in one read"
            )
        if self.reconnect_max_s < self.reconnect_min_s:
            raise ValueError("reconnect_max_s: must be >= reconnect_min_s")
        return self

    def char_time_s(self) -> float:
        """Time of one character on the line [s] (start + data + parity + stop bits)."""
        bits = 1 + self.bytesize + (0 if self.parity == "N" else 1) + self.stopbits
        return bits / self.baud


__all__ = ["MAX_READ_COUNT", "IndicatorConfig", "RegisterMap"]
