"""Driver of the HY9648 panel indicator (and comparable RS-485 meters) over Modbus RTU.

Transport: pymodbus' :class:`~pymodbus.client.AsyncModbusSerialClient` over pyserial, so the
``port`` may be ``/dev/ttyUSB0``, a pseudo-terminal, or ``socket://host:port`` (RTU over TCP).
``kind = "modbus-tcp"`` uses :class:`~pymodbus.client.AsyncModbusTcpClient` instead (MBAP).

Everything device-specific is configuration (:class:`RegisterMap`, :class:`IndicatorConfig`
in :mod:`drivers.indicator_config`), with the defaults of the design note
``hardware-protocols.md`` §1; the registers are decoded into an :class:`IndicatorReading` by the
pure functions of :mod:`drivers.indicator_reading`. Both are re-exported here.

Guarantees
----------
* :meth:`ModbusIndicator.read` returns a value only from a complete frame whose CRC, device id,
  function and byte count were checked, decoded from a single block read (value, decimals and
  status come from the same frame).
* A reply that is complete on the line (at least as many bytes as the expected frame, then
  :attr:`ModbusIndicator.frame_end_s` of silence) but that pymodbus did not accept (bad CRC,
  garbled function or byte count) is discarded at once and retried: it does not cost
  ``timeout_s``. RTU framing only (``modbus-tcp`` has no CRC).
* After any other failed attempt the driver waits until the line has been quiet for
  ``quiet_s`` and drops any bytes received meanwhile, so a late reply is not taken as the
  answer to the next request. Modbus RTU has no transaction id: a slave that answers later than
  ``timeout_s + quiet_s`` cannot be told apart from a timely one; keep ``timeout_s`` above the
  meter's worst-case reply time.
* Failures raise typed :class:`~drivers.errors.IndicatorError` subclasses carrying the last
  frames in hex. A lost port fails the pending attempt at once and is reopened on the next
  call, with exponential back-off between ``reconnect_min_s`` and ``reconnect_max_s``.
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from typing import Any, Literal

from pymodbus.client import AsyncModbusSerialClient, AsyncModbusTcpClient
from pymodbus.exceptions import ModbusException
from pymodbus.framer import FramerType

from drivers.backoff import ReconnectBackoff
from drivers.errors import (
    IndicatorCRCError,
    IndicatorLinkDown,
    IndicatorNoReply,
    IndicatorProtocolError,
    IndicatorTimeout,
)
from drivers.indicator_config import MAX_READ_COUNT, IndicatorConfig, RegisterMap
from drivers.indicator_reading import IndicatorReading, decode_block, reading_from_status
from drivers.wire_bytes import FrameLog, crc_ok


class ModbusIndicator:
    """Asyncio driver of a Modbus indicator. Not safe for concurrent calls from several
    tasks; the daemon's sampler owns it.

    Parameters
    ----------
    config : IndicatorConfig
    """

    def __init__(self, config: IndicatorConfig) -> None:
        self.config = config
        self.name = config.name
        self.frames = FrameLog(config.frame_log_size)
        self._client: AsyncModbusSerialClient | AsyncModbusTcpClient | None = None
        self._backoff = ReconnectBackoff(config.reconnect_min_s, config.reconnect_max_s)
        self._rx_attempt = b""
        self._rx_buffer = b""
        self._last_rx_monotonic = 0.0
        self._rx_event = asyncio.Event()
        self._lock = asyncio.Lock()

    # ---------------------------------------------------------------- connection
    def _trace_packet(self, sending: bool, data: bytes) -> bytes:
        if sending:
            self.frames.add("tx", data)
        else:
            # pymodbus passes its whole receive buffer, which restarts after it discards a
            # frame: rebuild the raw byte stream of this attempt.
            prev = self._rx_buffer
            self._rx_attempt += data[len(prev) :] if data.startswith(prev) else data
            self._rx_buffer = data
            self._last_rx_monotonic = time.monotonic()
            self._rx_event.set()
        return data

    def _trace_connect(self, connected: bool) -> None:
        if not connected:
            self._rx_event.set()  # wake a waiting attempt: the port is gone

    @property
    def frame_end_s(self) -> float:
        """Silence after which a received RTU frame is over [s]: t3.5, but at least 20 ms,
        since USB adapters hand bytes over in bursts (FTDI latency timer: 16 ms)."""
        return max(3.5 * self.config.char_time_s(), 0.02)

    def _make_client(self) -> AsyncModbusSerialClient | AsyncModbusTcpClient:
        cfg = self.config
        if cfg.kind == "modbus-tcp":
            return AsyncModbusTcpClient(
                cfg.host,
                port=cfg.tcp_port,
                framer=FramerType.SOCKET,
                timeout=cfg.timeout_s,
                retries=0,
                reconnect_delay=0,
                trace_packet=self._trace_packet,
                trace_connect=self._trace_connect,
            )
        return AsyncModbusSerialClient(
            cfg.port,
            framer=FramerType.RTU,
            baudrate=cfg.baud,
            bytesize=cfg.bytesize,
            parity=cfg.parity,
            stopbits=cfg.stopbits,
            timeout=cfg.timeout_s,
            retries=0,
            reconnect_delay=0,
            trace_packet=self._trace_packet,
            trace_connect=self._trace_connect,
        )

    @property
    def connected(self) -> bool:
        """True while the port is open."""
        return self._client is not None and self._client.connected

    def _endpoint(self) -> str:
        cfg = self.config
        return f"{cfg.host}:{cfg.tcp_port}" if cfg.kind == "modbus-tcp" else cfg.port

    async def connect(self) -> None:
        """Open the port now (otherwise the first :meth:`read` does).

        Raises
        ------
        IndicatorLinkDown
            The port cannot be opened (the back-off delay grows).
        """
        async with self._lock:
            await self._ensure_connected(force=True)

    async def _ensure_connected(self, force: bool = False) -> None:
        if self.connected:
            return
        wait_s = self._backoff.remaining_s(time.monotonic())
        if not force and wait_s > 0:
            raise IndicatorLinkDown(
                self.name,
                f"{self._endpoint()} down; next reconnect in {wait_s:.2f} s",
                self.frames.snapshot(),
            )
        if self._client is not None:
            self._client.close()
        self._client = self._make_client()
        ok = await self._client.connect()
        if not ok or not self._client.connected:
            self._client.close()
            self._client = None
            self._backoff.failed()
            self.frames.note(f"connect {self._endpoint()} failed")
            raise IndicatorLinkDown(
                self.name, f"cannot open {self._endpoint()}", self.frames.snapshot()
            )
        self._backoff.succeeded()
        self.frames.note(f"connected {self._endpoint()}")

    async def close(self) -> None:
        """Close the port. A later :meth:`read` reopens it."""
        if self._client is not None:
            self._client.close()
            self._client = None

    # ---------------------------------------------------------------- requests
    async def _quiet(self) -> None:
        """Wait until the line has been quiet for ``quiet_s``; drop what arrived meanwhile."""
        quiet_s = self.config.timeout_s if self.config.quiet_s is None else self.config.quiet_s
        start = time.monotonic()
        while True:
            now = time.monotonic()
            last = max(start, self._last_rx_monotonic)
            if now - last >= quiet_s or now - start > 5 * quiet_s + 1.0:
                break
            await asyncio.sleep(min(0.01, quiet_s))
        if self._client is not None:
            self._client.ctx.recv_buffer = b""

    def _reply_complete(self, expect_size: int) -> bool:
        """As many bytes as the expected reply (or an exception reply) arrived."""
        rx = self._rx_attempt
        return len(rx) >= expect_size or (len(rx) >= 5 and bool(rx[1] & 0x80))

    async def _await_call(
        self, task: asyncio.Future[Any], expect_size: int
    ) -> Literal["done", "rejected", "lost"]:
        """Wait for the pymodbus request ``task``.

        Returns ``"done"`` once it finished; ``"lost"`` as soon as the port is lost (pymodbus
        would wait out ``timeout_s``); ``"rejected"`` (RTU only) when a reply-sized frame
        arrived and the line then stayed quiet for :attr:`frame_end_s` without pymodbus
        accepting it (it drops a frame with a bad CRC and keeps waiting until ``timeout_s``).
        """
        rtu = self.config.kind == "modbus-rtu"
        while not task.done():
            if not self.connected:
                return "lost"
            timeout: float | None = None
            if rtu and self._reply_complete(expect_size):
                idle = time.monotonic() - self._last_rx_monotonic
                if idle >= self.frame_end_s:
                    return "rejected"
                timeout = self.frame_end_s - idle
            self._rx_event.clear()
            more = asyncio.ensure_future(self._rx_event.wait())
            try:
                await asyncio.wait(
                    {task, more}, timeout=timeout, return_when=asyncio.FIRST_COMPLETED
                )
            finally:
                more.cancel()
        return "done"

    async def _attempt(self, call: Any, expect_size: int) -> Any:
        """One request/response; returns the pymodbus response or raises a typed error."""
        assert self._client is not None
        self._rx_attempt = self._rx_buffer = b""
        self._rx_event = asyncio.Event()  # bound to the running loop, not the first one used
        task = asyncio.ensure_future(call())
        try:
            outcome = await self._await_call(task, expect_size)
        finally:
            if not task.done():
                task.cancel()
        if outcome != "done":
            with contextlib.suppress(asyncio.CancelledError, ModbusException):
                await task
            rx = self._rx_attempt
            if rx:
                self.frames.add("rx", rx)
            if outcome == "lost":
                raise IndicatorLinkDown(self.name, "link lost", self.frames.snapshot())
            # The whole reply is on the line and was rejected: no late byte will follow, so
            # neither the rest of timeout_s nor quiet_s is needed before the next attempt.
            if self._client is not None:
                self._client.ctx.recv_buffer = b""
            frames = self.frames.snapshot()
            if crc_ok(rx):
                raise IndicatorProtocolError(
                    self.name, f"reply not accepted ({len(rx)} bytes, CRC ok)", frames
                )
            raise IndicatorCRCError(self.name, "CRC mismatch; reply discarded", frames)
        try:
            response = task.result()
        except ModbusException as exc:
            rx = self._rx_attempt
            if rx:
                self.frames.add("rx", rx)
            if not self.connected:  # no quiet: the port is reopened anyway
                raise IndicatorLinkDown(
                    self.name, f"link lost: {exc}", self.frames.snapshot()
                ) from exc
            await self._quiet()
            frames = self.frames.snapshot()
            if not rx:
                raise IndicatorNoReply(
                    self.name, f"no reply within {self.config.timeout_s} s", frames
                ) from exc
            # As many bytes as a reply (or an exception reply) arrived, yet no valid frame:
            # the reply was corrupted on the line.
            if len(rx) >= expect_size or (len(rx) == 5 and rx[1] & 0x80 and not crc_ok(rx)):
                raise IndicatorCRCError(self.name, "CRC mismatch; reply discarded", frames) from exc
            raise IndicatorTimeout(
                self.name, f"incomplete reply ({len(rx)} bytes) within timeout", frames
            ) from exc
        self.frames.add("rx", self._rx_attempt)
        if response.isError():
            raise IndicatorProtocolError(
                self.name,
                f"Modbus exception code {getattr(response, 'exception_code', '?')}",
                self.frames.snapshot(),
            )
        return response

    async def _with_retries(self, call: Any, expect_size: int) -> Any:
        await self._ensure_connected()
        last: Exception | None = None
        for _ in range(self.config.retries + 1):
            if not self.connected:
                await self._ensure_connected()
            try:
                return await self._attempt(call, expect_size)
            except (IndicatorTimeout, IndicatorLinkDown) as exc:
                last = exc
                if isinstance(exc, IndicatorLinkDown):
                    await self.close()
                    self._backoff.dropped()
                    raise
        assert last is not None
        raise last

    async def read(self) -> IndicatorReading:
        """One reading (value, decimals and status from one block read).

        Raises
        ------
        IndicatorNoReply, IndicatorCRCError, IndicatorTimeout
            After ``retries + 1`` failed attempts.
        IndicatorLinkDown
            Port closed, lost, or in reconnect back-off.
        IndicatorProtocolError
            Exception response or malformed content.
        IndicatorOverRange
            Status flags over/under-range and ``over_range_policy == "raise"``.
        """
        cfg = self.config
        start, count = cfg.registers.read_block(cfg.decimals is None)
        async with self._lock:

            async def call() -> Any:
                assert self._client is not None
                if cfg.registers.read_function == 4:
                    return await self._client.read_input_registers(
                        start, count=count, device_id=cfg.device_id
                    )
                return await self._client.read_holding_registers(
                    start, count=count, device_id=cfg.device_id
                )

            response = await self._with_retries(call, 5 + 2 * count)
            t_mono, t_wall = time.monotonic(), time.time()
            regs = list(response.registers)
            if len(regs) != count:
                raise IndicatorProtocolError(
                    self.name, f"{len(regs)} registers, expected {count}", self.frames.snapshot()
                )
            try:
                counts, decimals, status = decode_block(regs, cfg, start)
            except ValueError as exc:
                raise IndicatorProtocolError(self.name, str(exc), self.frames.snapshot()) from exc
        regmap = cfg.registers
        return reading_from_status(
            self.name,
            counts,
            decimals,
            status,
            (regmap.over_range_bit, regmap.under_range_bit, regmap.moving_bit),
            cfg.over_range_policy,
            self.frames.snapshot(),
            t_mono,
            t_wall,
        )

    async def zero(self) -> None:
        """Zero the meter with the configured strategy (no-op for ``"none"``)."""
        cfg = self.config
        regmap = cfg.registers
        if cfg.zero_strategy == "none":
            return
        async with self._lock:

            async def call() -> Any:
                assert self._client is not None
                if cfg.zero_strategy == "command":
                    return await self._client.write_register(
                        regmap.command_address, regmap.zero_command, device_id=cfg.device_id
                    )
                if cfg.zero_strategy == "write_zero":
                    return await self._client.write_registers(
                        regmap.value_address, [0, 0], device_id=cfg.device_id
                    )
                return await self._client.write_coil(
                    regmap.zero_coil_address, True, device_id=cfg.device_id
                )

            await self._with_retries(call, 8)


__all__ = [
    "MAX_READ_COUNT",
    "IndicatorConfig",
    "IndicatorReading",
    "ModbusIndicator",
    "RegisterMap",
    "decode_block",
    "reading_from_status",
]
