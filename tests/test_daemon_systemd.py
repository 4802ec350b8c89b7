"""The real ``cablecal serve`` process speaks systemd's notify protocol on a test socket.

No emulated cell here: the indicator's port does not exist (an unplugged adapter) and the robot
is manual, so this also shows the daemon comes up and stays up without its devices.
"""

from __future__ import annotations

import socket
import threading
import time
from pathlib import Path

import httpx
import pytest

from daemon.cli.emulated import Process

pytestmark = pytest.mark.timeout(120)


class NotifyListener:
    """A datagram socket standing in for systemd; records (monotonic time, message)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(str(path))
        self.sock.settimeout(0.2)
        self.messages: list[tuple[float, str]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                data = self.sock.recv(4096)
            except TimeoutError:
                continue
            except OSError:
                return
            for line in data.decode().splitlines():
                self.messages.append((time.monotonic(), line))

    def times(self, key: str) -> list[float]:
        return [t for t, m in list(self.messages) if m.startswith(key)]

    def wait_for(self, key: str, timeout_s: float) -> float:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if found := self.times(key):
                return found[0]
            time.sleep(0.05)
        raise AssertionError(f"no {key} within {timeout_s} s; got {self.messages[-5:]}")

    def close(self) -> None:
        self._stop.set()
        self.sock.close()


def test_ready_status_watchdog_and_a_hung_loop_stops_the_pings(tmp_path: Path) -> None:
    listener = NotifyListener(tmp_path / "notify.sock")
    env = {
        "NOTIFY_SOCKET": str(tmp_path / "notify.sock"),
        "WATCHDOG_USEC": "1000000",  # WatchdogSec=1: a ping every 0.5 s
        "CABLECAL_STATE_DIR": str(tmp_path),
        "CABLECAL_API_TOKEN": "tok-0123456789abcdef",
        "CABLECAL_DEBUG_ROUTES": "true",
        "CABLECAL_INDICATOR__PORT": str(tmp_path / "no-such-adapter"),
        "CABLECAL_LOG_JSON": "true",
    }
    import sys

    proc = Process(
        [sys.executable, "-m", "daemon", "serve", "--port", "0"], tmp_path / "d.log", env
    )
    try:
        serving = proc.wait_line("SERVING ", timeout_s=60)
        t_ready = listener.wait_for("READY=1", 10)
        url = __import__("json").loads(serving)["url"]
        # READY only once the API answers.
        assert httpx.get(url + "/api/v1/health").status_code == 200
        assert listener.times("STATUS=")
        listener.wait_for("WATCHDOG=1", 5)
        time.sleep(2.0)
        pings = [t for t in listener.times("WATCHDOG=1") if t > t_ready]
        assert len(pings) >= 3, pings

        # Hang the main loop for 3 s: the pings must stop (they come from that loop).
        def hang() -> None:
            httpx.post(
                url + "/api/v1/debug/hang",
                json={"seconds": 3.0},
                headers={"Authorization": "Bearer tok-0123456789abcdef"},
                timeout=30,
            )

        t_hang = time.monotonic()
        th = threading.Thread(target=hang)
        th.start()
        th.join()
        t_back = time.monotonic()
        time.sleep(1.5)
        during = [t for t in listener.times("WATCHDOG=1") if t_hang + 0.7 < t < t_back - 0.3]
        after = [t for t in listener.times("WATCHDOG=1") if t > t_back]
        print(f"pings during the 3 s hang: {len(during)}, in 1.5 s after: {len(after)}")
        assert during == [], "pinged while the main loop was blocked (side-thread pinger?)"
        assert len(after) >= 2
        assert proc.popen.poll() is None
        # The status line names the devices; the unplugged indicator is in error.
        statuses = [m for _, m in listener.messages if m.startswith("STATUS=")]
        assert any("indicator" in s for s in statuses), statuses
    finally:
        code = proc.stop()
        time.sleep(0.5)  # let the listener thread drain the last datagrams
        listener.close()
    assert any(m == "STOPPING=1" for _, m in listener.messages)
    # uvicorn re-raises SIGTERM after a clean shutdown; systemd counts that as success.
    assert code in (0, -15), proc.log_tail()
    assert "Application shutdown complete" in proc.log_tail()
