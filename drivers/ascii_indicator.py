"""Indicator in continuous ASCII output (design note §1, optional transport).

Frame: STX, sign, 7 characters with the decimal point, one status character (hex digit of
the status bits), 2 hex checksum characters (sum of sign..status modulo 256), CR LF. The
layout is the assumed default; a meter with another layout needs its own parser.

The port is opened with
pyserial (any URL) and read through ``loop.add_reader`` on its file descriptor.
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from typing import Annotated, Literal

import serial
from pydantic import BaseModel, ConfigDict, Field

from drivers.errors import (
    IndicatorCRCError,
    IndicatorLinkDown,
    IndicatorNoReply,
    IndicatorProtocolError,
)
from drivers.indicator_reading import IndicatorReading, reading_from_status
from drivers.wire_bytes import FrameLog

STX, CRLF = b"\x02", b"\r\n"
FRAME_SIZE = 1 + 8 + 1 + 2 + 2


def parse_ascii_frame(frame: bytes) -> tuple[int, int, int]:
    """``(counts, decimals, status)`` of one complete frame (STX … CR LF).

    Raises
    ------
    ValueError
        Wrong size, delimiters or characters; message starts with ``"checksum"`` on a
        checksum mismatch.
    """
    if len(frame) != FRAME_SIZE or frame[:1] != STX or frame[-2:] != CRLF:
        raise ValueError(f"malformed frame {frame!r}")
    body, check = frame[1:10], frame[10:12]
    if f"{sum(body) & 0xFF:02X}".encode() != check:
        raise ValueError(f"checksum mismatch in {frame!r}")
    text = body[:8].decode("ascii")
    if text[0] not in "+-":
        raise ValueError(f"bad sign in {frame!r}")
    digits = text[1:]
    decimals = len(digits) - digits.index(".") - 1 if "." in digits else 0
    magnitude = int(digits.replace(".", ""))
    return (-magnitude if text[0] == "-" else magnitude), decimals, int(body[8:9], 16)


class AsciiIndicatorConfig(BaseModel):
    """Configuration of :class:`AsciiIndicator`."""

    model_config = ConfigDict(extra="forbid")

    kind: Literal["ascii"] = "ascii"
    name: str = "indicator"
    port: str = "/dev/ttyUSB0"
    baud: Annotated[int, Field(ge=300, le=921600)] = 9600
    parity: Literal["N", "E", "O"] = "N"
    stopbits: Literal[1, 2] = 1
    timeout_s: Annotated[float, Field(gt=0)] = 1.0
    over_range_bit: Annotated[int, Field(ge=0, le=3)] = 0
    under_range_bit: Annotated[int, Field(ge=0, le=3)] = 1
    moving_bit: Annotated[int, Field(ge=0, le=3)] = 2
    over_range_policy: Literal["raise", "flag"] = "raise"
    reconnect_min_s: Annotated[float, Field(gt=0)] = 0.1
    frame_log_size: Annotated[int, Field(ge=1)] = 16


class AsciiIndicator:
    """Reads the next complete, checksum-valid frame from a continuous stream."""

    def __init__(self, config: AsciiIndicatorConfig) -> None:
        self.config = config
        self.name = config.name
        self.frames = FrameLog(config.frame_log_size)
        self._serial: serial.Serial | None = None
        self._buf = b""
        self._event = asyncio.Event()
        self._lost = False
        self._next_attempt = 0.0

    @property
    def connected(self) -> bool:
        return self._serial is not None and not self._lost

    async def connect(self) -> None:
        """Open the port. Raises :class:`IndicatorLinkDown`."""
        await self._close_port()
        cfg = self.config
        try:
            self._serial = serial.serial_for_url(
                cfg.port, baudrate=cfg.baud, parity=cfg.parity, stopbits=cfg.stopbits, timeout=0
            )
        except (serial.SerialException, OSError) as exc:
            self._next_attempt = time.monotonic() + cfg.reconnect_min_s
            raise IndicatorLinkDown(self.name, f"cannot open {cfg.port}: {exc}") from exc
        self._lost = False
        self._buf = b""
        asyncio.get_running_loop().add_reader(self._serial.fileno(), self._on_readable)

    def _on_readable(self) -> None:
        assert self._serial is not None
        try:
            data = self._serial.read(4096)
        except (serial.SerialException, OSError):
            self._lost = True
            asyncio.get_running_loop().remove_reader(self._serial.fileno())
            self._event.set()
            return
        self._buf = (self._buf + data)[-4096:]
        self._event.set()

    async def _close_port(self) -> None:
        if self._serial is not None:
            with contextlib.suppress(Exception):
                asyncio.get_running_loop().remove_reader(self._serial.fileno())
            self._serial.close()
            self._serial = None

    async def close(self) -> None:
        """Close the port."""
        await self._close_port()

    async def read(self) -> IndicatorReading:
        """The next complete frame received after this call started.

        Raises
        ------
        IndicatorNoReply, IndicatorCRCError, IndicatorLinkDown, IndicatorProtocolError,
        IndicatorOverRange
        """
        cfg = self.config
        if not self.connected:
            if time.monotonic() < self._next_attempt:
                raise IndicatorLinkDown(self.name, f"{cfg.port} down", self.frames.snapshot())
            await self.connect()
        self._buf = b""  # only frames that start after this call
        deadline = time.monotonic() + cfg.timeout_s
        bad: str | None = None
        while True:
            start = self._buf.find(STX)
            end = self._buf.find(CRLF, start + 1) if start >= 0 else -1
            if start >= 0 and end >= 0:
                frame = self._buf[start : end + 2]
                self._buf = self._buf[end + 2 :]
                self.frames.add("rx", frame)
                try:
                    counts, decimals, status = parse_ascii_frame(frame)
                except ValueError as exc:
                    bad = str(exc)
                    continue
                break
            if self._lost:
                await self._close_port()
                self._next_attempt = time.monotonic() + cfg.reconnect_min_s
                raise IndicatorLinkDown(self.name, f"{cfg.port} lost", self.frames.snapshot())
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                if bad is not None and bad.startswith("checksum"):
                    raise IndicatorCRCError(self.name, bad, self.frames.snapshot())
                if bad is not None:
                    raise IndicatorProtocolError(self.name, bad, self.frames.snapshot())
                raise IndicatorNoReply(
                    self.name, f"no frame within {cfg.timeout_s} s", self.frames.snapshot()
                )
            self._event.clear()
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(remaining):
                    await self._event.wait()
        t_mono, t_wall = time.monotonic(), time.time()
        return reading_from_status(
            self.name,
            counts,
            decimals,
            status,
            (cfg.over_range_bit, cfg.under_range_bit, cfg.moving_bit),
            cfg.over_range_policy,
            self.frames.snapshot(),
            t_mono,
            t_wall,
        )

    async def zero(self) -> None:
        """A streaming meter cannot be zeroed over the line: no-op (zero it by hand)."""
