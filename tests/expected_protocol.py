"""Test helpers in the spirit of PyMeasure's ``expected_protocol``: a scripted device states
the exact bytes the driver must send and the bytes it gets back, over a real pseudo-terminal
or a loopback TCP socket, and fails if anything differs or is left over.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import termios
import tty
from collections.abc import AsyncIterator, Sequence

Exchange = tuple[bytes, bytes]


class ProtocolMismatch(AssertionError):
    """The driver sent other bytes than scripted, too few, or too many."""


async def _run_script(
    read: asyncio.StreamReader, write: asyncio.StreamWriter | int, exchanges: Sequence[Exchange]
) -> None:
    for i, (expect, reply) in enumerate(exchanges):
        try:
            got = await asyncio.wait_for(read.readexactly(len(expect)), 5.0)
        except (TimeoutError, asyncio.IncompleteReadError) as exc:
            raise ProtocolMismatch(
                f"exchange {i}: expected {expect.hex(' ')}, got nothing"
            ) from exc
        if got != expect:
            raise ProtocolMismatch(f"exchange {i}: expected {expect.hex(' ')}, got {got.hex(' ')}")
        if reply:
            if isinstance(write, int):
                os.write(write, reply)
            else:
                write.write(reply)
                await write.drain()


async def _leftover(reader: asyncio.StreamReader) -> bytes:
    with contextlib.suppress(asyncio.TimeoutError):
        return await asyncio.wait_for(reader.read(4096), 0.05)
    return b""


@contextlib.asynccontextmanager
async def expected_protocol_pty(exchanges: Sequence[Exchange]) -> AsyncIterator[str]:
    """Yield the path of a pty whose device side plays ``exchanges``
    (``(bytes the driver must send, bytes answered)``; an empty answer = no reply)."""
    master, slave = os.openpty()
    tty.setraw(master, termios.TCSANOW)
    tty.setraw(slave, termios.TCSANOW)
    loop = asyncio.get_running_loop()
    reader = asyncio.StreamReader()
    os.set_blocking(master, False)

    def on_readable() -> None:
        try:
            data = os.read(master, 4096)
        except OSError:
            return
        reader.feed_data(data)

    loop.add_reader(master, on_readable)
    task = asyncio.ensure_future(_run_script(reader, master, exchanges))
    try:
        yield os.ttyname(slave)
        await asyncio.wait_for(asyncio.shield(task), 5.0)
        extra = await _leftover(reader)
        if extra:
            raise ProtocolMismatch(f"unexpected extra bytes {extra.hex(' ')}")
    finally:
        task.cancel()
        with contextlib.suppress(BaseException):
            await task
        loop.remove_reader(master)
        os.close(master)
        os.close(slave)


@contextlib.asynccontextmanager
async def expected_protocol_tcp(exchanges: Sequence[Exchange]) -> AsyncIterator[int]:
    """Yield a loopback TCP port whose single peer plays ``exchanges``."""
    done: asyncio.Future[None] = asyncio.get_running_loop().create_future()

    async def handle(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            await _run_script(reader, writer, exchanges)
            extra = await _leftover(reader)
            if extra:
                raise ProtocolMismatch(f"unexpected extra bytes {extra.hex(' ')}")
            if not done.done():
                done.set_result(None)
        except BaseException as exc:
            if not done.done():
                done.set_exception(exc)
        finally:
            writer.close()

    server = await asyncio.start_server(handle, "127.0.0.1", 0)
    try:
        yield server.sockets[0].getsockname()[1]
        await asyncio.wait_for(done, 5.0)
    finally:
        server.close()
        await server.wait_closed()
