"""Slave side of Modbus, written independently of pymodbus: request framing (RTU, MBAP)
as pure functions, and the emulated indicator's register bank as a PDU handler.

The drivers use pymodbus as the master; keeping the emulator's codec separate means a
driver test checks two implementations against each other (and minimalmodbus/mbpoll check
this one).
"""

from __future__ import annotations

import struct
from collections.abc import Callable

from drivers.wire_bytes import add_crc, crc_ok, int32_to_words, words_to_int32
from simulator.cell import EmulatedCell

#: Modbus exception codes.
ILLEGAL_FUNCTION, ILLEGAL_ADDRESS, ILLEGAL_VALUE = 1, 2, 3

#: Fixed-size requests by function code (whole RTU frame incl. id and CRC).
_FIXED_RTU_SIZE = {1: 8, 2: 8, 3: 8, 4: 8, 5: 8, 6: 8}


def decode_rtu_request(buf: bytes) -> tuple[int, int, bytes | None]:
    """Find one request in ``buf``.

    Returns
    -------
    used : int
        Bytes consumed (0: wait for more).
    device_id : int
    pdu : bytes or None
        Function code and data without id and CRC; ``None`` when nothing complete yet or
        bytes were discarded (bad CRC or unknown function: one byte is dropped to re-sync).
    """
    if len(buf) < 4:
        return 0, 0, None
    fc = buf[1]
    if fc in _FIXED_RTU_SIZE:
        size = _FIXED_RTU_SIZE[fc]
    elif fc in (15, 16):
        if len(buf) < 7:
            return 0, 0, None
        size = 9 + buf[6]
    else:
        return 1, 0, None
    if len(buf) < size:
        return 0, 0, None
    frame = buf[:size]
    if not crc_ok(frame):
        return 1, 0, None
    return size, frame[0], frame[1:-2]


def encode_rtu(device_id: int, pdu: bytes) -> bytes:
    """RTU frame of a reply PDU."""
    return add_crc(bytes([device_id]) + pdu)


def decode_mbap(buf: bytes) -> tuple[int, tuple[int, int] | None, bytes | None]:
    """One MBAP (Modbus TCP) frame: ``(used, (transaction_id, unit_id), pdu)``; used 0 = wait.

    Raises ``ValueError`` on a non-zero protocol id or an impossible length.
    """
    if len(buf) < 7:
        return 0, None, None
    tid, pid, length, unit = struct.unpack(">HHHB", buf[:7])
    if pid != 0 or not 2 <= length <= 254:
        raise ValueError(f"bad MBAP header {buf[:7].hex(' ')}")
    if len(buf) < 6 + length:
        return 0, None, None
    return 6 + length, (tid, unit), buf[7 : 6 + length]


def encode_mbap(transaction_id: int, unit_id: int, pdu: bytes) -> bytes:
    """MBAP frame of a reply PDU."""
    return struct.pack(">HHHB", transaction_id, 0, len(pdu) + 1, unit_id) + pdu


def exception_pdu(fc: int, code: int) -> bytes:
    """Modbus exception reply."""
    return bytes([fc | 0x80, code])


def read_registers_pdu(
    pdu: bytes, read: Callable[[int, int], list[int] | None], allowed: tuple[int, ...] = (3, 4)
) -> bytes:
    """Answer an FC03/FC04 request with ``read(address, count)`` (``None`` = illegal)."""
    fc = pdu[0]
    if fc not in allowed:
        return exception_pdu(fc, ILLEGAL_FUNCTION)
    if len(pdu) != 5:
        return exception_pdu(fc, ILLEGAL_VALUE)
    address, count = struct.unpack(">HH", pdu[1:5])
    if not 1 <= count <= 125:
        return exception_pdu(fc, ILLEGAL_VALUE)
    values = read(address, count)
    if values is None:
        return exception_pdu(fc, ILLEGAL_ADDRESS)
    return bytes([fc, 2 * count]) + b"".join(v.to_bytes(2, "big") for v in values)


class IndicatorBank:
    """The emulated HY9648's registers, computed from the cell at each request."""

    def __init__(self, cell: EmulatedCell) -> None:
        self.cell = cell
        self.map = cell.config.indicator.registers

    def snapshot(self) -> dict[int, int]:
        """All mapped registers at this instant."""
        m, cell = self.map, self.cell
        counts, status, length_mm = cell.indicator_state()
        order = m.word_order
        regs: dict[int, int] = {}

        def put32(address: int | None, value: int) -> None:
            if address is not None:
                regs[address], regs[address + 1] = int32_to_words(value, order)

        put32(m.value_address, counts)
        if m.decimals_address is not None:
            regs[m.decimals_address] = cell.decimals
        put32(m.raw_count_address, round(length_mm / 0.004))
        put32(m.magnification_address, cell.magnification_x1000())
        if m.status_address is not None:
            regs[m.status_address] = status
        put32(m.preset_address, cell.preset_counts)
        regs[m.command_address] = 0
        regs[m.slave_address_register] = cell.slave_address
        regs[m.baud_code_register] = cell.baud_code
        return regs

    def read(self, address: int, count: int) -> list[int] | None:
        regs = self.snapshot()
        lo, hi = min(regs), max(regs)
        if address < lo or address + count - 1 > hi:
            return None
        return [regs.get(a, 0) for a in range(address, address + count)]

    def handle(self, pdu: bytes) -> bytes:
        """Reply PDU for a request PDU."""
        fc = pdu[0]
        m = self.map
        if fc in (3, 4):
            return read_registers_pdu(pdu, self.read, allowed=(m.read_function,))
        if fc == 6 and len(pdu) == 5:
            address, value = struct.unpack(">HH", pdu[1:5])
            if address == m.command_address:
                if value == m.zero_command:
                    self.cell.zero()
                elif value == m.preset_command:
                    self.cell.set_display_mm(self.cell.preset_counts / 10**self.cell.decimals)
                else:
                    return exception_pdu(fc, ILLEGAL_VALUE)
            elif address == m.slave_address_register:
                if not 1 <= value <= 247:
                    return exception_pdu(fc, ILLEGAL_VALUE)
                self.cell.slave_address = value  # stored; takes effect after a restart
            elif address == m.baud_code_register:
                self.cell.baud_code = value
            else:
                return exception_pdu(fc, ILLEGAL_ADDRESS)
            return pdu  # echo
        if fc == 16 and len(pdu) >= 6:
            address, count, nbytes = struct.unpack(">HHB", pdu[1:6])
            data = pdu[6:]
            if count != 2 or nbytes != 4 or len(data) != 4:
                return exception_pdu(fc, ILLEGAL_VALUE)
            words = [int.from_bytes(data[0:2], "big"), int.from_bytes(data[2:4], "big")]
            value = words_to_int32(words, m.word_order)
            if address == m.value_address:
                self.cell.set_display_mm(value / 10**self.cell.decimals)
            elif address == m.preset_address:
                self.cell.preset_counts = value
            else:
                return exception_pdu(fc, ILLEGAL_ADDRESS)
            return pdu[:5]
        if fc == 5 and len(pdu) == 5:
            address, value = struct.unpack(">HH", pdu[1:5])
            if address != m.zero_coil_address:
                return exception_pdu(fc, ILLEGAL_ADDRESS)
            if value not in (0xFF00, 0x0000):
                return exception_pdu(fc, ILLEGAL_VALUE)
            if value == 0xFF00:
                self.cell.zero()
            return pdu
        return exception_pdu(fc, ILLEGAL_FUNCTION)


def ascii_frame(counts: int, decimals: int, status: int) -> bytes:
    """Continuous-output frame: STX, sign, 7 characters with the decimal point, status
    (one hex digit of the status bits), 2 hex checksum characters, CR LF.

    The checksum is the sum of the bytes from the sign to the status character, modulo 256.
    This layout is the emulator's assumption (design note §1), not a vendor's documented one.
    """
    sign = "-" if counts < 0 else "+"
    magnitude = abs(counts)
    if decimals:
        text = f"{magnitude // 10**decimals}.{magnitude % 10**decimals:0{decimals}d}"
    else:
        text = str(magnitude)
    body = f"{sign}{text:>7}"[:8].replace(" ", "0") + f"{status & 0xF:X}"
    checksum = sum(body.encode("ascii")) & 0xFF
    return b"\x02" + body.encode("ascii") + f"{checksum:02X}".encode("ascii") + b"\r\n"
