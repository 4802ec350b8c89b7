"""Run the emulated cell and the daemon as real processes (tests, benchmarks, ``make run``).

Everything here drives the real command line (``python -m daemon simulate`` / ``serve``) and
finds the endpoints from the ``READY`` and ``SERVING`` lines they print. Nothing is mocked: the
daemon talks to the emulated cell over the pty and TCP exactly as it would to a real cell.
"""

from __future__ import annotations

import contextlib
import json
import os
import queue
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from types import TracebackType
from typing import Any

import httpx

from simulator.config import EMULATED_NOISE_MM

#: Indicator noise (1σ) of :func:`fast_cell_toml` [mm]: the emulated cell's default.
FAST_CELL_NOISE_MM = EMULATED_NOISE_MM

# The daemon's settings for :func:`fast_cell_toml`'s cell: its baud rate, a short settle window.
FAST_DAEMON_ENV = {
    "CABLECAL_INDICATOR__BAUD": "115200",
    "CABLECAL_SAMPLER__SETTLE_S": "0.3",
    "CABLECAL_SAMPLER__SETTLE_TOL_MM": "0.08",
    "CABLECAL_JOBS__NOISE_MM": str(FAST_CELL_NOISE_MM),
}


def fast_cell_toml(n_poses: int, seed: int, move_s: float = 0.4, dwell_s: float = 1.0) -> str:
    """sim.toml of a fast EMULATED cell: ``n_poses`` poses visited once, ``move_s`` moves and
    ``dwell_s`` dwells, indicator at 115200 baud with :data:`FAST_CELL_NOISE_MM` noise, robot
    controllers on free TCP ports."""
    return f"""
seed = {seed}
[robot]
n_poses = {n_poses}
move_time_s = {move_s}
dwell_s = {dwell_s}
loop = false
[indicator]
noise_mm = {FAST_CELL_NOISE_MM}
decimals = 2
baud = 115200
[robot_socketcmd]
port = 0
[robot_modbus]
port = 0
"""


class Process:
    """A child process whose stdout is read line by line in a thread (never blocks the pipe);
    stderr goes to ``log_path``."""

    def __init__(self, argv: list[str], log_path: Path, env: dict[str, str] | None = None) -> None:
        self.argv = argv
        self.log_path = log_path
        self._log = open(log_path, "ab")  # noqa: SIM115 - closed in stop()
        self.popen = subprocess.Popen(
            argv,
            stdout=subprocess.PIPE,
            stderr=self._log,
            env={**os.environ, **(env or {})},
            start_new_session=True,
        )
        self.lines: queue.Queue[str] = queue.Queue()
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.popen.stdout is not None
        for raw in self.popen.stdout:
            self.lines.put(raw.decode(errors="replace").rstrip("\n"))

    def wait_line(self, prefix: str, timeout_s: float = 60.0) -> str:
        """The rest of the first stdout line starting with ``prefix``.

        Raises
        ------
        RuntimeError
            The process exited or the line did not come within ``timeout_s``; the message
            carries the tail of the process's stderr log.
        """
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            try:
                line = self.lines.get(timeout=0.2)
            except queue.Empty:
                if self.popen.poll() is not None:
                    break
                continue
            if line.startswith(prefix):
                return line[len(prefix) :].strip()
        raise RuntimeError(
            f"{' '.join(self.argv[:4])}: no {prefix!r} line (exit {self.popen.poll()}); "
            f"log tail:\n{self.log_tail()}"
        )

    def log_tail(self, n: int = 40) -> str:
        """The last ``n`` lines of the stderr log."""
        if not self._log.closed:
            self._log.flush()
        try:
            return "\n".join(self.log_path.read_text(errors="replace").splitlines()[-n:])
        except OSError:
            return ""

    def kill(self) -> None:
        """SIGKILL (no clean-up at all: the crash test)."""
        with contextlib.suppress(ProcessLookupError):
            self.popen.send_signal(signal.SIGKILL)
        self.popen.wait(timeout=10)

    def stop(self, timeout_s: float = 15.0) -> int | None:
        """SIGTERM, then SIGKILL after ``timeout_s``; returns the exit code."""
        if self.popen.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                self.popen.send_signal(signal.SIGTERM)
            try:
                self.popen.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                self.kill()
        self._log.close()
        return self.popen.returncode


class EmulatedCellProcess(Process):
    """``cablecal simulate --config FILE``; :attr:`ready` is the READY mapping."""

    def __init__(self, config_path: Path, workdir: Path) -> None:
        super().__init__(
            [sys.executable, "-m", "daemon", "simulate", "--config", str(config_path)],
            workdir / "simulator.log",
        )
        self.ready: dict[str, Any] = json.loads(self.wait_line("READY "))
        self.ready_path = workdir / "cell.json"
        self.ready_path.write_text(json.dumps(self.ready), encoding="utf-8")

    def control(self, cmd: str, **fields: Any) -> dict[str, Any]:
        """One command on the cell's control port."""
        from simulator.runner import ControlClient

        client = ControlClient(str(self.ready["control"]))
        try:
            return client(cmd, **fields)
        finally:
            client.close()


class DaemonProcess(Process):
    """``cablecal serve --simulated-cell READY.json --port PORT`` (default 0: any free port);
    :attr:`url`, :attr:`token`."""

    def __init__(
        self,
        ready_path: Path,
        state_dir: Path,
        token: str,
        env: dict[str, str] | None = None,
        extra_args: list[str] | None = None,
        port: int = 0,
    ) -> None:
        self.token = token
        super().__init__(
            [
                sys.executable,
                "-m",
                "daemon",
                "serve",
                "--simulated-cell",
                str(ready_path),
                "--port",
                str(port),
                *(extra_args or []),
            ],
            state_dir / "daemon.log",
            env={
                "CABLECAL_STATE_DIR": str(state_dir),
                "CABLECAL_API_TOKEN": token,
                "CABLECAL_LOG_JSON": "true",
                **(env or {}),
            },
        )
        self.serving: dict[str, Any] = json.loads(self.wait_line("SERVING ", timeout_s=90))
        self.url: str = self.serving["url"]

    def client(self, timeout_s: float = 30.0) -> httpx.Client:
        """An HTTP client with the bearer token, based at ``/api/v1``."""
        return httpx.Client(
            base_url=self.url + "/api/v1",
            headers={"Authorization": f"Bearer {self.token}"},
            timeout=timeout_s,
        )


class Cell:
    """Emulated cell plus daemon, as a context manager (stopped in reverse order)."""

    def __init__(
        self,
        workdir: Path,
        sim_toml: str,
        token: str = "cell-test-token-emulated",
        daemon_env: dict[str, str] | None = None,
    ) -> None:
        self.workdir = workdir
        self.sim_toml = sim_toml
        self.token = token
        self.daemon_env = daemon_env or {}
        self.sim: EmulatedCellProcess | None = None
        self.daemon: DaemonProcess | None = None

    def __enter__(self) -> Cell:
        path = self.workdir / "sim.toml"
        path.write_text(self.sim_toml, encoding="utf-8")
        self.sim = EmulatedCellProcess(path, self.workdir)
        try:
            self.start_daemon()
        except BaseException:
            self.sim.stop()
            raise
        return self

    def start_daemon(self) -> DaemonProcess:
        """(Re)start the daemon on the same state directory."""
        assert self.sim is not None
        self.daemon = DaemonProcess(
            self.sim.ready_path, self.workdir, self.token, env=self.daemon_env
        )
        return self.daemon

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if self.daemon is not None:
            self.daemon.stop()
        if self.sim is not None:
            self.sim.stop()


def wait_for(predicate: Any, timeout_s: float, interval_s: float = 0.25, what: str = "") -> Any:
    """Poll ``predicate()`` until it returns a truthy value; raises TimeoutError naming ``what``."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            raise TimeoutError(f"timed out after {timeout_s} s waiting for {what}")
        time.sleep(interval_s)
