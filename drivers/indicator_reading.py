"""An indicator reading and its decoding: pure functions from register values to a
:class:`IndicatorReading` (no I/O), shared by the Modbus and ASCII indicator drivers."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

from drivers.errors import IndicatorOverRange
from drivers.indicator_config import IndicatorConfig
from drivers.wire_bytes import words_to_int32


@dataclass(frozen=True)
class IndicatorReading:
    """One indicator reading.

    Attributes
    ----------
    length_mm : float
        Displayed value / 10^decimals [mm] (relative to where the meter was zeroed).
    counts : int
        Raw display value.
    decimals : int
    status : int
        Status register (0 when the map has none).
    over_range, moving : bool
        Decoded status bits (``over_range`` covers over- and under-range).
    t_monotonic_s : float
        :func:`time.monotonic` when the reply was complete.
    t_wall : float
        :func:`time.time` at the same moment (Unix seconds).
    """

    length_mm: float
    counts: int
    decimals: int
    status: int
    over_range: bool
    moving: bool
    t_monotonic_s: float
    t_wall: float


def reading_from_status(
    device: str,
    counts: int,
    decimals: int,
    status: int,
    bits: tuple[int, int, int],
    over_range_policy: Literal["raise", "flag"],
    frames_hex: Sequence[str],
    t_monotonic_s: float,
    t_wall: float,
) -> IndicatorReading:
    """An :class:`IndicatorReading` from a decoded display value and status word.

    ``bits`` are the status bits of over-range, under-range and moving. With
    ``over_range_policy = "raise"`` an over/under-range status raises
    :class:`IndicatorOverRange` (carrying ``frames_hex``) instead.
    """
    over_bit, under_bit, moving_bit = bits
    over = bool(status >> over_bit & 1 or status >> under_bit & 1)
    if over and over_range_policy == "raise":
        raise IndicatorOverRange(device, f"status 0x{status:04x}: over/under-range", frames_hex)
    return IndicatorReading(
        length_mm=counts / 10**decimals,
        counts=counts,
        decimals=decimals,
        status=status,
        over_range=over,
        moving=bool(status >> moving_bit & 1),
        t_monotonic_s=t_monotonic_s,
        t_wall=t_wall,
    )


def decode_block(registers: list[int], config: IndicatorConfig, start: int) -> tuple[int, int, int]:
    """``(counts, decimals, status)`` from the registers of one block read at ``start``.

    Raises
    ------
    ValueError
        Decimals register out of 0..6.
    """
    regmap = config.registers
    off = regmap.value_address - start
    counts = words_to_int32(registers[off : off + 2], regmap.word_order)
    if config.decimals is not None:
        decimals = config.decimals
    else:
        assert regmap.decimals_address is not None  # checked by IndicatorConfig
        decimals = registers[regmap.decimals_address - start]
        if decimals > 6:
            raise ValueError(f"decimals register reads {decimals}, expected 0..6")
    status = 0 if regmap.status_address is None else registers[regmap.status_address - start]
    return counts, decimals, status


__all__ = ["IndicatorReading", "decode_block", "reading_from_status"]
