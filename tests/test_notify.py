"""sd_notify over a test AF_UNIX datagram socket: messages, no-op outside systemd, abstract
names, send errors, and the watchdog loop (pings stop while the event loop is blocked)."""

from __future__ import annotations

import asyncio
import logging
import os
import socket
import tempfile
import threading
import time
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest

from daemon.process.notify import Notifier, watchdog_loop


class NotifyServer:
    """What systemd does: a datagram socket; a reader thread stamps each message on arrival."""

    def __init__(self, address: str | bytes) -> None:
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(address)
        self.sock.settimeout(0.05)
        self.received: list[tuple[float, str]] = []  # (time.monotonic(), message)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="notify-test-server", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                data = self.sock.recv(4096)
            except TimeoutError:
                continue
            with self._lock:
                self.received.append((time.monotonic(), data.decode()))

    def messages(self, settle_s: float = 0.2) -> list[str]:
        time.sleep(settle_s)
        with self._lock:
            return [m for _, m in self.received]

    def stamped(self) -> list[tuple[float, str]]:
        with self._lock:
            return list(self.received)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2)
        self.sock.close()


@pytest.fixture
def socket_path() -> Iterator[str]:
    # Short directory: AF_UNIX paths are limited to 107 bytes, pytest's tmp_path can be longer.
    with tempfile.TemporaryDirectory(prefix="cc-notify-") as d:
        yield str(Path(d) / "notify")


@pytest.fixture
def server(socket_path: str) -> Iterator[NotifyServer]:
    srv = NotifyServer(socket_path)
    yield srv
    srv.close()


def test_messages_arrive(server: NotifyServer, socket_path: str) -> None:
    n = Notifier.from_env({"NOTIFY_SOCKET": socket_path})
    assert n.enabled
    assert n.ready()
    assert n.status("2 devices up\nsampler auto")
    assert n.watchdog()
    assert n.stopping()
    assert n.reloading()
    assert n.extend_timeout(1.5)
    n.close()
    msgs = server.messages()
    assert msgs[:4] == ["READY=1", "STATUS=2 devices up sampler auto", "WATCHDOG=1", "STOPPING=1"]
    reload_lines = msgs[4].split("\n")
    assert reload_lines[0] == "RELOADING=1"
    assert reload_lines[1].startswith("MONOTONIC_USEC=") and int(reload_lines[1][15:]) > 0
    assert msgs[5] == "EXTEND_TIMEOUT_USEC=1500000"


def test_ready_with_status(server: NotifyServer, socket_path: str) -> None:
    Notifier(socket_path).ready("listening on 127.0.0.1:8080")
    assert server.messages() == ["READY=1\nSTATUS=listening on 127.0.0.1:8080"]


def test_abstract_socket_name() -> None:
    name = f"cablecal-test-{uuid.uuid4().hex}"
    srv = NotifyServer(b"\0" + name.encode())
    try:
        n = Notifier.from_env({"NOTIFY_SOCKET": "@" + name})
        assert n.ready() and n.watchdog()
        assert srv.messages() == ["READY=1", "WATCHDOG=1"]
    finally:
        srv.close()


def test_noop_without_notify_socket(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("NOTIFY_SOCKET", raising=False)
    monkeypatch.setenv("WATCHDOG_USEC", "30000000")
    n = Notifier.from_env()
    assert not n.enabled
    assert n.watchdog_interval_s is None
    assert not any([n.ready(), n.status("x"), n.watchdog(), n.stopping(), n.reloading()])
    assert n._sock is None  # not even a socket was opened
    asyncio.run(asyncio.wait_for(watchdog_loop(n, lambda: "ok"), timeout=1))  # returns at once


@pytest.mark.parametrize(
    ("env", "interval_s"),
    [
        ({"WATCHDOG_USEC": "30000000"}, 15.0),
        ({"WATCHDOG_USEC": "30000000", "WATCHDOG_PID": str(os.getpid())}, 15.0),
        ({"WATCHDOG_USEC": "30000000", "WATCHDOG_PID": str(os.getpid() + 1)}, None),
        ({"WATCHDOG_USEC": "30000000", "WATCHDOG_PID": "nope"}, None),
        ({"WATCHDOG_USEC": "soon"}, None),
        ({"WATCHDOG_USEC": "0"}, None),
        ({}, None),
    ],
)
def test_watchdog_interval_from_env(env: dict[str, str], interval_s: float | None) -> None:
    n = Notifier.from_env({"NOTIFY_SOCKET": "/run/systemd/notify", **env})
    assert n.watchdog_interval_s == interval_s


def test_send_errors_are_logged_not_raised(
    socket_path: str, caplog: pytest.LogCaptureFixture
) -> None:
    n = Notifier(socket_path)  # nobody listens there
    with caplog.at_level(logging.DEBUG, logger="daemon.process.notify"):
        assert not n.ready()
        assert not n.watchdog()
    levels = [r.levelno for r in caplog.records if "sd_notify" in r.getMessage()]
    assert levels == [logging.WARNING, logging.DEBUG]  # one warning per run of failures
    srv = NotifyServer(socket_path)
    try:
        caplog.clear()
        with caplog.at_level(logging.INFO, logger="daemon.process.notify"):
            assert n.watchdog()
        assert "works again" in caplog.text
    finally:
        srv.close()


def test_bad_arguments() -> None:
    with pytest.raises(ValueError, match="notify_socket"):
        Notifier("@")
    with pytest.raises(ValueError, match="watchdog_usec"):
        Notifier("/run/x", watchdog_usec=0)
    with pytest.raises(ValueError, match="status_interval_s"):
        asyncio.run(watchdog_loop(Notifier(None), status_interval_s=0))


async def _run_for(coro_task: asyncio.Task[None], seconds: float) -> None:
    await asyncio.sleep(seconds)
    coro_task.cancel()
    with pytest.raises(asyncio.CancelledError):
        await coro_task


def test_watchdog_loop_pings_and_reports_status(server: NotifyServer, socket_path: str) -> None:
    n = Notifier(socket_path, watchdog_usec=100_000)  # ping every 0.05 s
    statuses = iter(["ok", "ok", "indicator down", "indicator down"])

    def health() -> str | None:
        return next(statuses, None)

    async def main() -> None:
        await _run_for(asyncio.create_task(watchdog_loop(n, health)), 0.4)

    asyncio.run(main())
    msgs = server.messages()
    assert msgs[0] == "WATCHDOG=1\nSTATUS=ok"
    assert msgs[1] == "WATCHDOG=1"  # unchanged status is not resent
    assert msgs[2] == "WATCHDOG=1\nSTATUS=indicator down"
    assert all(m == "WATCHDOG=1" for m in msgs[3:]) and len(msgs) >= 5


def test_watchdog_loop_pings_when_health_fails(
    server: NotifyServer, socket_path: str, caplog: pytest.LogCaptureFixture
) -> None:
    def health() -> str | None:
        raise RuntimeError("store closed")

    async def main() -> None:
        await _run_for(
            asyncio.create_task(watchdog_loop(Notifier(socket_path, 100_000), health)), 0.2
        )

    asyncio.run(main())
    assert server.messages()[:2] == ["WATCHDOG=1", "WATCHDOG=1"]
    assert "health callback" in caplog.text


def test_status_only_without_watchdog(server: NotifyServer, socket_path: str) -> None:
    async def main() -> None:
        task = asyncio.create_task(
            watchdog_loop(Notifier(socket_path), lambda: "idle", status_interval_s=0.05)
        )
        await _run_for(task, 0.2)

    asyncio.run(main())
    assert server.messages() == ["STATUS=idle"]  # no WATCHDOG=1 when systemd runs no watchdog


def test_hung_event_loop_stops_the_pings(
    server: NotifyServer, socket_path: str, caplog: pytest.LogCaptureFixture
) -> None:
    """A callback blocks the loop for 3 ping periods: no ping may arrive meanwhile (nothing
    pings from a side thread), and the pings resume once the loop turns again."""
    interval_s = 0.2
    block_s = 3 * interval_s
    n = Notifier(socket_path, watchdog_usec=round(2 * interval_s * 1e6))
    assert n.watchdog_interval_s == pytest.approx(interval_s)
    block: dict[str, float] = {}

    def hang() -> None:
        block["start"] = time.monotonic()
        time.sleep(block_s)  # deliberately blocking: a hung serial read done on the loop
        block["end"] = time.monotonic()

    async def main() -> None:
        threads_before = set(threading.enumerate())
        task = asyncio.create_task(watchdog_loop(n))
        await asyncio.sleep(2.5 * interval_s)
        assert set(threading.enumerate()) == threads_before  # the loop started no thread
        asyncio.get_running_loop().call_soon(hang)
        await asyncio.sleep(0)  # hang() runs before this task resumes
        await _run_for(task, 3 * interval_s)

    with caplog.at_level(logging.WARNING, logger="daemon.process.notify"):
        asyncio.run(main())
    server.messages()
    pings = [t for t, m in server.stamped() if m == "WATCHDOG=1"]
    before = [t for t in pings if t < block["start"]]
    during = [t for t in pings if block["start"] + 0.05 < t < block["end"]]
    after = [t for t in pings if t >= block["end"]]
    assert len(before) >= 2
    assert during == []
    assert len(after) >= 2  # one right away when the loop turns again, then on rhythm
    assert "event loop was blocked" in caplog.text
