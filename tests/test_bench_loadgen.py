"""bench.api_bench's load generator against a tiny keep-alive HTTP server that, like uvicorn,
closes a connection left idle: the generator must not count its own stale pooled
connections as service errors, and must name the kind of every error it does count."""

from __future__ import annotations

import asyncio
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:  # bench/ is a top-level package of the repo, not installed
    sys.path.insert(0, str(REPO))

from bench.api_bench import _load  # noqa: E402

SERVER_IDLE_S = 0.5  # the server closes a keep-alive connection idle this long
SLOW_S = 0.15  # answer time inside the slow windows (grows the client's pool)
SLOW_WINDOWS_S = ((0.0, 0.4), (1.6, 2.0))  # [start, end) after the first request [s]


def _serve(ready: threading.Event, out: dict[str, int], stop: threading.Event) -> None:
    t0: list[float] = []

    async def handle(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            while True:
                await asyncio.wait_for(reader.readuntil(b"\r\n\r\n"), SERVER_IDLE_S)
                if not t0:
                    t0.append(time.perf_counter())
                t = time.perf_counter() - t0[0]
                if any(a <= t < b for a, b in SLOW_WINDOWS_S):
                    await asyncio.sleep(SLOW_S)
                code = b"401 Unauthorized" if t > 2.2 else b"200 OK"
                writer.write(b"HTTP/1.1 " + code + b"\r\nContent-Length: 2\r\n\r\nok")
                await writer.drain()
        except (TimeoutError, asyncio.IncompleteReadError, ConnectionError):
            writer.close()  # idle too long (or the client left): close, as uvicorn does

    async def main() -> None:
        server = await asyncio.start_server(handle, "127.0.0.1", 0)
        out["port"] = server.sockets[0].getsockname()[1]
        ready.set()
        while not stop.is_set():
            await asyncio.sleep(0.05)
        server.close()

    asyncio.run(main())


@pytest.fixture
def url() -> Iterator[str]:
    ready, stop, out = threading.Event(), threading.Event(), {}
    thread = threading.Thread(target=_serve, args=(ready, out, stop), daemon=True)
    thread.start()
    assert ready.wait(10)
    yield f"http://127.0.0.1:{out['port']}/api/v1/status"
    stop.set()
    thread.join(10)


@pytest.mark.slow
@pytest.mark.parametrize("idle_max_s", [0.25, 1e9])
def test_stale_keepalive_connections_are_not_service_errors(url: str, idle_max_s: float) -> None:
    """After the first slow window the pool holds idle connections; the server closes them
    before the second slow window needs them. Reused anyway (``idle_max_s`` 1e9, the old
    generator), each reads EOF: ``IncompleteReadError``. After 2.2 s the server answers 401:
    counted as ``HTTP 401``."""
    r = _load(url, "token", rate_hz=100.0, duration_s=2.5, idle_max_s=idle_max_s)
    assert r["requests"] == 250
    assert r["error_kinds"].get("HTTP 401", 0) >= 20  # the last ~0.3 s
    stale = r["error_kinds"].get("IncompleteReadError", 0)
    if idle_max_s < SERVER_IDLE_S:
        assert set(r["error_kinds"]) == {"HTTP 401"}, r
    else:
        assert stale > 0, r
    assert r["errors"] == sum(r["error_kinds"].values())
