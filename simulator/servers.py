"""Transports of the emulated cell: the indicator on a pseudo-terminal (RTU, paced at the
baud rate, or ASCII stream) and on TCP, the emulated robot controllers on TCP.

All servers run on one asyncio loop. Each has ``start()``, ``stop()`` and ``link_down(s)``
(the endpoint goes away for ``s`` seconds and comes back at the same address).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import os
import re
import struct
import termios
import time
import tty
from pathlib import Path

from simulator.cell import EmulatedCell
from simulator.wire import (
    IndicatorBank,
    ascii_frame,
    decode_mbap,
    decode_rtu_request,
    encode_mbap,
    encode_rtu,
    exception_pdu,
    read_registers_pdu,
)

log = logging.getLogger("cablecal.simulator")


def char_time_s(baud: int, parity: str, stopbits: int) -> float:
    """Seconds per character: start + 8 data + parity + stop bits."""
    return (1 + 8 + (0 if parity == "N" else 1) + stopbits) / baud


def t35_s(baud: int, char_s: float) -> float:
    """Modbus RTU inter-frame silence: 3.5 characters, fixed 1.75 ms above 19200 baud."""
    return 0.00175 if baud > 19200 else 3.5 * char_s


# --------------------------------------------------------------------------- pty
class PtyIndicator:
    """Emulated indicator as Modbus RTU slave (or ASCII streamer) on a pseudo-terminal.

    The public path is a symlink ``link_path`` to the current ``/dev/pts/N`` (like
    ``/dev/serial/by-id``): after :meth:`link_down` a new pty is created and the symlink
    re-pointed, so a driver reconnects to the same path.

    Pacing (``pace``): the half-duplex line is modelled. A request occupies the line for its
    length in characters (starting no earlier than t3.5 after the previous reply), the slave
    answers t3.5 after the request ended, and the reply's bytes are written to the pty at the
    moments their last bit would arrive.
    """

    def __init__(self, cell: EmulatedCell, link_path: Path) -> None:
        self.cell = cell
        self.ind = cell.config.indicator
        self.bank = IndicatorBank(cell)
        self.link_path = link_path
        self.char_s = char_time_s(self.ind.baud, self.ind.parity, self.ind.stopbits)
        self.t35_s = t35_s(self.ind.baud, self.char_s)
        self._master: int | None = None
        self._slave_keep: int | None = None
        self._buf = b""
        self._first_byte_t = 0.0
        self._wire_free_t = 0.0
        self._busy = False
        self._tasks: set[asyncio.Task[None]] = set()
        self._down = False
        self.requests = 0

    @property
    def pts_path(self) -> str | None:
        return None if self._master is None else os.ttyname(self._slave_keep or 0)

    def _open(self) -> None:
        master, slave = os.openpty()
        tty.setraw(slave, termios.TCSANOW)
        tty.setraw(master, termios.TCSANOW)
        os.set_blocking(master, False)
        self._master, self._slave_keep = master, slave
        tmp = self.link_path.with_name(self.link_path.name + ".tmp")
        with contextlib.suppress(FileNotFoundError):
            tmp.unlink()
        tmp.symlink_to(os.ttyname(slave))
        os.replace(tmp, self.link_path)
        loop = asyncio.get_running_loop()
        if self.ind.mode == "modbus":
            loop.add_reader(master, self._on_readable)
        else:
            self._spawn(self._ascii_stream())

    def _close(self) -> None:
        for task in list(self._tasks):
            task.cancel()
        if self._master is not None:
            with contextlib.suppress(Exception):
                asyncio.get_running_loop().remove_reader(self._master)
            os.close(self._master)
            self._master = None
        if self._slave_keep is not None:
            os.close(self._slave_keep)
            self._slave_keep = None
        self._buf = b""
        self._busy = False

    async def start(self) -> None:
        self._open()

    async def stop(self) -> None:
        self._close()
        with contextlib.suppress(FileNotFoundError):
            self.link_path.unlink()

    async def link_down(self, duration_s: float) -> None:
        """Unplug: close the pty (the driver's port reports hang-up), re-plug later."""
        if self._down:
            return
        self._down = True
        self._close()
        with contextlib.suppress(FileNotFoundError):
            self.link_path.unlink()
        await asyncio.sleep(duration_s)
        self._open()
        self._down = False

    def _spawn(self, coro: asyncio.Future[None] | asyncio.Task[None] | object) -> None:
        task: asyncio.Task[None] = asyncio.ensure_future(coro)  # type: ignore[arg-type]
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    def _on_readable(self) -> None:
        assert self._master is not None
        try:
            data = os.read(self._master, 4096)
        except BlockingIOError:
            return
        except OSError:
            data = b""  # EIO: no slave side open; keep listening
        if not data:
            return
        now = time.monotonic()
        if self._busy:
            log.debug("indicator busy, request bytes dropped: %s", data.hex(" "))
            return
        if not self._buf:
            self._first_byte_t = now
        self._buf += data
        while self._buf:
            used, dev_id, pdu = decode_rtu_request(self._buf)
            if used == 0:
                break
            self._buf = self._buf[used:]
            if pdu is None:
                continue
            frame_len = used
            self._handle(dev_id, pdu, frame_len)
            self._buf = b""  # a master sends one request at a time
            break

    def _handle(self, dev_id: int, pdu: bytes, request_len: int) -> None:
        self.requests += 1
        faults = self.cell.faults
        if dev_id not in (self.cell.config.indicator.device_id, 0):
            return  # another slave on the bus
        rng = self.cell.fault_rng
        if faults.indicator_drop_rate and rng.random() < faults.indicator_drop_rate:
            return  # request lost on the line: not executed, no reply
        reply_pdu = self.bank.handle(pdu)
        if dev_id == 0:
            return  # broadcast: no reply
        frame = bytearray(encode_rtu(dev_id, reply_pdu))
        if faults.indicator_crc_error_rate and rng.random() < faults.indicator_crc_error_rate:
            pos = int(rng.integers(1, len(frame) - 2))
            frame[pos] ^= 1 << int(rng.integers(0, 8))  # corrupt data, keep the old CRC
        self._busy = True
        self._spawn(self._send(bytes(frame), request_len, faults.indicator_reply_delay_s))

    async def _send(self, frame: bytes, request_len: int, delay_s: float) -> None:
        loop = asyncio.get_running_loop()
        try:
            if not self.ind.pace:
                if delay_s:
                    await asyncio.sleep(delay_s)
                self._write(frame)
                return
            # Monotonic and loop time are the same clock on Linux; use loop time for sleeps.
            offset = loop.time() - time.monotonic()
            req_start = max(self._first_byte_t, self._wire_free_t + self.t35_s)
            reply_start = req_start + request_len * self.char_s + self.t35_s + delay_s
            chunk = max(1, math.ceil(0.001 / self.char_s))  # about 1 ms of bytes per write
            sent = 0
            while sent < len(frame):
                n = min(chunk, len(frame) - sent)
                due = reply_start + (sent + n) * self.char_s + offset
                wait = due - loop.time()
                if wait > 0:
                    await asyncio.sleep(wait)
                self._write(frame[sent : sent + n])
                sent += n
            self._wire_free_t = reply_start + len(frame) * self.char_s
        finally:
            self._busy = False

    def _write(self, data: bytes) -> None:
        if self._master is None:
            return
        with contextlib.suppress(OSError):  # no reader or buffer full: bytes lost
            os.write(self._master, data)

    async def _ascii_stream(self) -> None:
        period = 1.0 / self.ind.ascii_rate_hz
        next_t = time.monotonic()
        while True:
            counts, status, _ = self.cell.indicator_state()
            frame = bytearray(ascii_frame(counts, self.cell.decimals, status))
            rng = self.cell.fault_rng
            faults = self.cell.faults
            if not (faults.indicator_drop_rate and rng.random() < faults.indicator_drop_rate):
                if (
                    faults.indicator_crc_error_rate
                    and rng.random() < faults.indicator_crc_error_rate
                ):
                    frame[3] ^= 0x01
                if self.ind.pace:
                    for i in range(len(frame)):
                        self._write(bytes(frame[i : i + 1]))
                        await asyncio.sleep(self.char_s)
                else:
                    self._write(bytes(frame))
            next_t += period
            await asyncio.sleep(max(0.0, next_t - time.monotonic()))


# --------------------------------------------------------------------------- TCP base
class TcpServer:
    """A loopback TCP server that can be taken down and brought back on the same port."""

    label = "tcp"

    def __init__(self, cell: EmulatedCell, host: str, port: int) -> None:
        self.cell = cell
        self.host = host
        self.port = port
        self._server: asyncio.Server | None = None
        self._writers: set[asyncio.StreamWriter] = set()
        self._down = False

    @property
    def endpoint(self) -> str:
        return f"{self.host}:{self.port}"

    async def start(self) -> None:
        self._server = await asyncio.start_server(
            self._client, self.host, self.port, reuse_address=True
        )
        self.port = self._server.sockets[0].getsockname()[1]

    async def stop(self) -> None:
        if self._server is not None:
            self._server.close()
            for writer in list(self._writers):
                writer.close()
            await self._server.wait_closed()
            self._server = None

    async def link_down(self, duration_s: float) -> None:
        """Close the listener and every connection; listen again after ``duration_s``."""
        if self._down:
            return
        self._down = True
        await self.stop()
        await asyncio.sleep(duration_s)
        await self.start()
        self._down = False

    async def _client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self._writers.add(writer)
        try:
            await self.serve(reader, writer)
        except (ConnectionError, asyncio.IncompleteReadError, ValueError) as exc:
            log.debug("%s client dropped: %s", self.label, exc)
        finally:
            self._writers.discard(writer)
            writer.close()

    async def serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        raise NotImplementedError

    async def reply(
        self,
        writer: asyncio.StreamWriter,
        data: bytes,
        drop_rate: float,
        delay_s: float,
        late_rate: float = 0.0,
        late_delay_s: float = 0.0,
    ) -> None:
        """Send ``data`` unless dropped by the fault settings, after ``delay_s`` (plus
        ``late_delay_s`` for the fraction ``late_rate`` of replies). The caller awaits this
        before reading the next request: replies stay in request order, as on one stream."""
        rng = self.cell.fault_rng
        if drop_rate and rng.random() < drop_rate:
            return
        if late_rate and rng.random() < late_rate:
            delay_s += late_delay_s
        if delay_s:
            await asyncio.sleep(delay_s)
        writer.write(data)
        await writer.drain()


class TcpIndicator(TcpServer):
    """Emulated indicator on TCP: RTU frames over TCP (``"rtu"``) or Modbus TCP (``"mbap"``)."""

    label = "indicator-tcp"

    def __init__(self, cell: EmulatedCell, host: str, port: int, framing: str) -> None:
        super().__init__(cell, host, port)
        self.framing = framing
        self.bank = IndicatorBank(cell)

    async def serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        buf = b""
        device_id = self.cell.config.indicator.device_id
        while data := await reader.read(4096):
            buf += data
            while True:
                faults = self.cell.faults
                if self.framing == "mbap":
                    used, head, pdu = decode_mbap(buf)
                    if used == 0 or head is None or pdu is None:
                        break
                    buf = buf[used:]
                    out = encode_mbap(head[0], head[1], self.bank.handle(pdu))
                else:
                    used, dev_id, rpdu = decode_rtu_request(buf)
                    if used == 0:
                        break
                    buf = buf[used:]
                    if rpdu is None or dev_id != device_id:
                        continue
                    frame = bytearray(encode_rtu(dev_id, self.bank.handle(rpdu)))
                    rate = faults.indicator_crc_error_rate
                    if rate and self.cell.fault_rng.random() < rate:
                        frame[2] ^= 0x10
                    out = bytes(frame)
                await self.reply(
                    writer, out, faults.indicator_drop_rate, faults.indicator_reply_delay_s
                )


# --------------------------------------------------------------------------- robots
_HS_REQUEST = re.compile(r"^i:(-?\d+),c:(.*)$", re.S)

#: Error codes of the emulated SocketCmd server (the real controller's codes are not public).
HS_OK, HS_UNKNOWN_COMMAND, HS_BAD_REQUEST = 0, 1, 2


def format_floats(values: list[float] | tuple[float, ...]) -> str:
    """``{v1,v2,…,}`` with six decimals and the controller's trailing comma."""
    return "{" + "".join(f"{v:.6f}," for v in values) + "}"


class HuashuSocketCmdServer(TcpServer):
    """Emulated Huashu III controller, SocketCmd text protocol (``@hs@`` terminated).

    Answers ``mot.getJntData(0)`` (joint angles [deg]) and ``mot.getLocData(0)``
    (X Y Z [mm] of the hook point, A B C [deg]); other commands get ``e:1``.
    """

    label = "huashu-socketcmd"

    async def serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        while True:
            raw = await reader.readuntil(b"@hs@")
            text = raw[:-4].decode("ascii", errors="replace").strip()
            match = _HS_REQUEST.match(text)
            if match is None:
                out = f"i:0,e:{HS_BAD_REQUEST},d:bad request@hs@"
            else:
                seq, cmd = match.group(1), match.group(2).strip()
                q = self.cell.reported_joints()
                if cmd == "mot.getJntData(0)":
                    out = f"i:{seq},e:{HS_OK},d:{format_floats(list(q))}@hs@"
                elif cmd == "mot.getLocData(0)":
                    out = f"i:{seq},e:{HS_OK},d:{format_floats(self.cell.tcp_pose(q))}@hs@"
                else:
                    out = f"i:{seq},e:{HS_UNKNOWN_COMMAND},d:unknown command@hs@"
            faults = self.cell.faults
            await self.reply(
                writer,
                out.encode("ascii"),
                faults.robot_drop_rate,
                faults.robot_reply_delay_s,
                faults.robot_late_rate,
                faults.robot_late_delay_s,
            )

    async def alarm(self, code: int, text: str) -> int:
        """Send an unsolicited ``i:-1`` alarm to every client; returns how many got it."""
        frame = f"i:-1,e:{code},d:{text}@hs@".encode("ascii", errors="replace")
        for writer in list(self._writers):
            writer.write(frame)
            with contextlib.suppress(ConnectionError):
                await writer.drain()
        return len(self._writers)


def ur_joint_registers(q_rad: float) -> tuple[int, int]:
    """UR layout: ``(angle register [mrad, unsigned, 0..2π), revolution counter)`` with
    ``q = reg/1000 + int16(rev)·2π`` (65535 for one negative turn)."""
    turns = math.floor(q_rad / (2 * math.pi))
    reg = round((q_rad - turns * 2 * math.pi) * 1000.0)
    if reg >= 6284:  # rounding reached a full turn
        reg, turns = reg - 6283, turns + 1
    return reg & 0xFFFF, turns & 0xFFFF


class UrModbusServer(TcpServer):
    """Emulated Universal-Robots-style Modbus TCP server: joint angles at 270–275 (mrad,
    unsigned), joint speeds at 280–285 (mrad/s, int16), revolution counters at 320–325.
    Other addresses below 1000 read as 0. FC03 and FC04 read the same registers."""

    label = "robot-modbus"

    def registers(self) -> dict[int, int]:
        now = time.monotonic()
        q = self.cell.reported_joints(now)
        q_prev = self.cell.reported_joints(now - 0.01)
        regs: dict[int, int] = {}
        for j in range(6):
            reg, rev = ur_joint_registers(math.radians(float(q[j])))
            regs[270 + j], regs[320 + j] = reg, rev
            speed = round(math.radians(float(q[j] - q_prev[j])) / 0.01 * 1000.0)
            regs[280 + j] = max(-32768, min(32767, speed)) & 0xFFFF
        return regs

    async def serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        buf = b""
        while data := await reader.read(4096):
            buf += data
            while True:
                used, head, pdu = decode_mbap(buf)
                if used == 0 or head is None or pdu is None:
                    break
                buf = buf[used:]
                regs = self.registers()

                def read(address: int, count: int, regs: dict[int, int] = regs) -> list[int] | None:
                    if address + count > 1000:
                        return None
                    return [regs.get(a, 0) for a in range(address, address + count)]

                if pdu[0] in (3, 4):
                    reply = read_registers_pdu(pdu, read)
                else:
                    reply = exception_pdu(pdu[0], 1)
                faults = self.cell.faults
                await self.reply(
                    writer,
                    encode_mbap(head[0], head[1], reply),
                    faults.robot_drop_rate,
                    faults.robot_reply_delay_s,
                    faults.robot_late_rate,
                    faults.robot_late_delay_s,
                )


__all__ = [
    "HuashuSocketCmdServer",
    "PtyIndicator",
    "TcpIndicator",
    "TcpServer",
    "UrModbusServer",
    "struct",
]
