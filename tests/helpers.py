"""Helpers shared by the tests (not installed): emulated-cell configurations, the truth a
reading is checked against, and a real uvicorn server on loopback."""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from simulator.config import SimConfig
from simulator.runner import SimulatorThread


def _merge(base: dict[str, Any], extra: dict[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for key, value in extra.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = _merge(out[key], value)
        else:
            out[key] = value
    return out


def sim_config(**sections: Any) -> SimConfig:
    """A :class:`SimConfig` with every TCP port free-chosen (0) and ``sections`` merged in,
    e.g. ``sim_config(indicator={"baud": 115200})``."""
    base: dict[str, Any] = {
        "robot_socketcmd": {"port": 0},
        "robot_modbus": {"port": 0},
        "control": {"port": 0},
    }
    return SimConfig.model_validate(_merge(base, sections))


def start_emulated_cell(hold: bool = False, **sections: Any) -> SimulatorThread:
    """Start the emulated cell of :func:`sim_config` ``(**sections)`` in a thread; ``hold``
    keeps the robot still. The caller stops it."""
    sim = SimulatorThread(sim_config(**sections)).start()
    if hold:
        try:
            sim.control("hold", on=True)
        except BaseException:
            sim.stop()
            raise
    return sim


def host_port(endpoint: str | None) -> tuple[str, int]:
    """``"host:port"`` of a READY line as ``(host, port)``."""
    assert endpoint is not None
    host, port = endpoint.rsplit(":", 1)
    return host, int(port)


def deviation_from_truth_deg(
    sim: SimulatorThread, joints_deg: Any, t_from_s: float, t_to_s: float
) -> float:
    """``min_t max_j |q_j(t) - reading_j|`` [deg] over t in [t_from_s, t_to_s] (monotonic
    seconds): how far a reading is from the cell's reported joints at any instant of that
    span (0.2 ms grid, then 2 µs around its best instant; joints move at up to a few hundred
    deg/s, so the grid resolves about 0.002 deg)."""
    import numpy as np

    reading = np.asarray(joints_deg, dtype=float)

    def best(times_s: Any) -> tuple[float, float]:
        devs = [float(np.abs(sim.cell.reported_joints(t) - reading).max()) for t in times_s]
        k = int(np.argmin(devs))
        return float(times_s[k]), devs[k]

    t_best, _ = best(np.arange(t_from_s, t_to_s + 0.0002, 0.0002))
    return best(np.arange(t_best - 0.0002, t_best + 0.0002, 0.000002))[1]


def closed_by_server(s: socket.socket, timeout_s: float) -> bytes | None:
    """What the server sent on ``s`` before it closed the connection, or None when it kept the
    connection open for ``timeout_s``."""
    s.settimeout(timeout_s)
    got = b""
    try:
        while chunk := s.recv(4096):
            got += chunk
    except TimeoutError:
        return None
    except ConnectionResetError:
        pass
    return got


@contextmanager
def served_app(app: Any, **options: Any) -> Iterator[tuple[str, int]]:
    """A real uvicorn server on loopback running ``app`` in a thread with ``options``
    (:func:`daemon.api.http.server.uvicorn_options`); yields its (host, port) and stops it after."""
    import uvicorn

    config = uvicorn.Config(app, host="127.0.0.1", port=0, log_config=None, **options)
    srv = uvicorn.Server(config)
    thread = threading.Thread(target=srv.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 60
    while not srv.started:
        assert time.monotonic() < deadline and thread.is_alive()
        time.sleep(0.02)
    try:
        yield "127.0.0.1", srv.servers[0].sockets[0].getsockname()[1]
    finally:
        srv.should_exit = True
        thread.join(15)
