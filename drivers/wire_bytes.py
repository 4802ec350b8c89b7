"""Byte-level helpers shared by the drivers: CRC-16/Modbus, hex dumps, a frame ring buffer,
and pure builders/parsers of the Modbus RTU frames the indicator driver exchanges.

The pure functions are what the golden-byte tests pin; the drivers send exactly these bytes
(pymodbus builds them, and the tests check pymodbus agrees).
"""

from __future__ import annotations

import struct
import time
from collections import deque


def crc16_modbus(data: bytes) -> int:
    """CRC-16/MODBUS (poly 0xA001 reflected, init 0xFFFF) of ``data``.

    The frame carries it low byte first: ``frame + crc.to_bytes(2, "little")``.
    """
    crc = 0xFFFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return crc


def add_crc(frame: bytes) -> bytes:
    """``frame`` followed by its CRC, low byte first."""
    return frame + crc16_modbus(frame).to_bytes(2, "little")


def crc_ok(frame: bytes) -> bool:
    """True when the last two bytes of ``frame`` are the CRC of the rest."""
    return len(frame) >= 4 and crc16_modbus(frame[:-2]) == int.from_bytes(frame[-2:], "little")


def to_hex(data: bytes) -> str:
    """``b"\\x01\\x03"`` → ``"01 03"``."""
    return data.hex(" ")


class FrameLog:
    """Ring buffer of the last ``size`` frames, for error reports.

    Each entry is ``"<t_monotonic_s> tx|rx <hex>"``.
    """

    def __init__(self, size: int = 16) -> None:
        self._frames: deque[str] = deque(maxlen=size)

    def add(self, direction: str, data: bytes) -> None:
        """Record ``data`` sent (``"tx"``) or received (``"rx"``)."""
        self._frames.append(f"{time.monotonic():.6f} {direction} {to_hex(data)}")

    def note(self, text: str) -> None:
        """Record a free-text event (connect, disconnect, timeout)."""
        self._frames.append(f"{time.monotonic():.6f} -- {text}")

    def snapshot(self) -> tuple[str, ...]:
        """The recorded frames, oldest first."""
        return tuple(self._frames)


def rtu_read_request(device_id: int, function: int, address: int, count: int) -> bytes:
    """FC03/FC04 read request: ``id fc addr_hi addr_lo cnt_hi cnt_lo crc_lo crc_hi``."""
    if function not in (3, 4):
        raise ValueError(f"function: expected 3 or 4, got {function}")
    return add_crc(struct.pack(">BBHH", device_id, function, address, count))


def rtu_write_single_request(device_id: int, address: int, value: int) -> bytes:
    """FC06 write single register."""
    return add_crc(struct.pack(">BBHH", device_id, 6, address, value))


def rtu_write_multiple_request(device_id: int, address: int, values: list[int]) -> bytes:
    """FC16 write multiple registers."""
    head = struct.pack(">BBHHB", device_id, 16, address, len(values), 2 * len(values))
    return add_crc(head + b"".join(v.to_bytes(2, "big") for v in values))


def rtu_write_coil_request(device_id: int, address: int, on: bool) -> bytes:
    """FC05 write single coil (``0xFF00`` on, ``0x0000`` off)."""
    return add_crc(struct.pack(">BBHH", device_id, 5, address, 0xFF00 if on else 0))


def rtu_read_response_size(count: int) -> int:
    """Bytes in a normal FC03/FC04 response to a read of ``count`` registers."""
    return 5 + 2 * count


def parse_rtu_read_response(frame: bytes, device_id: int, function: int, count: int) -> list[int]:
    """Decode a complete FC03/FC04 response frame to its register values.

    Raises
    ------
    ValueError
        Wrong length, CRC, device id, function, byte count, or a Modbus exception response
        (message starts with ``"exception"``).
    """
    if len(frame) == 5 and frame[1] == function | 0x80:
        if not crc_ok(frame):
            raise ValueError("CRC mismatch")
        raise ValueError(f"exception code {frame[2]}")
    if len(frame) != rtu_read_response_size(count):
        raise ValueError(f"length {len(frame)}, expected {rtu_read_response_size(count)}")
    if not crc_ok(frame):
        raise ValueError("CRC mismatch")
    if frame[0] != device_id or frame[1] != function or frame[2] != 2 * count:
        raise ValueError("header mismatch")
    return [int.from_bytes(frame[3 + 2 * i : 5 + 2 * i], "big") for i in range(count)]


def words_to_int32(words: list[int], word_order: str) -> int:
    """Two registers to a signed 32-bit integer; ``word_order`` ``"ABCD"`` (high word first)
    or ``"CDAB"`` (low word first)."""
    if len(words) != 2:
        raise ValueError(f"words: expected 2 registers, got {len(words)}")
    hi, lo = (words[0], words[1]) if word_order == "ABCD" else (words[1], words[0])
    value = (hi << 16) | lo
    return value - (1 << 32) if value & 0x80000000 else value


def int32_to_words(value: int, word_order: str) -> list[int]:
    """Inverse of :func:`words_to_int32`."""
    raw = value & 0xFFFFFFFF
    hi, lo = raw >> 16, raw & 0xFFFF
    return [hi, lo] if word_order == "ABCD" else [lo, hi]
