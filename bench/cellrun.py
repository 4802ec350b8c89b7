"""What the benches of the sampler under load share: the EMULATED cell's configuration, the
daemon started from a given source tree, a tree unpacked from a git revision, the indicator
poll rate over a span of work, and the watch of ``/health`` latency and RSS.

Used by bench/sampler_priority.py, bench/hardening5.py, bench/hardening5_identify.py and
bench/hardening6.py.
"""

from __future__ import annotations

import contextlib
import os
import subprocess
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, TypeVar

import httpx
from prometheus_client.parser import text_string_to_metric_families

from daemon.cli.emulated import Cell, DaemonProcess

T = TypeVar("T")

ROOT = Path(__file__).resolve().parents[1]
HEALTH_INTERVAL_S = 0.05
HEALTH_TIMEOUT_S = 5.0

#: The EMULATED cell: indicator at 9600 baud (the HY9648's default, where the sampler polls
#: at about 26 Hz), a robot that moves and dwells.
SIM = """
seed = 11
[robot]
n_poses = 400
move_time_s = 0.5
dwell_s = 1.0
[indicator]
baud = 9600
[robot_socketcmd]
port = 0
[robot_modbus]
port = 0
"""


def indicator_polls(url: str) -> float:
    """The daemon's ``cablecal_device_polls_total`` of the indicator."""
    text = httpx.get(url + "/metrics", timeout=10).text
    for family in text_string_to_metric_families(text):
        for s in family.samples:
            if s.name == "cablecal_device_polls_total" and s.labels.get("role") == "indicator":
                return float(s.value)
    raise RuntimeError("no cablecal_device_polls_total{role=indicator} in /metrics")


def poll_rate(url: str, work: Callable[[], T]) -> tuple[dict[str, Any], T]:
    """Run ``work()`` and measure the indicator poll rate meanwhile (polls over wall time);
    ``{"duration_s", "polls", "poll_rate_hz", "load_average_1min"}`` and what ``work``
    returned."""
    polls0, t0 = indicator_polls(url), time.monotonic()
    result = work()
    polls1, t1 = indicator_polls(url), time.monotonic()
    rate = {
        "duration_s": round(t1 - t0, 2),
        "polls": int(polls1 - polls0),
        "poll_rate_hz": round((polls1 - polls0) / (t1 - t0), 3),
        "load_average_1min": round(os.getloadavg()[0], 2),
    }
    return rate, result


@contextlib.contextmanager
def unpacked(rev: str) -> Iterator[Path]:
    """The source tree of git revision ``rev`` in a temporary directory (``git archive``)."""
    with tempfile.TemporaryDirectory(prefix="cablecal-bench-tree-") as tmp:
        archive = subprocess.run(
            ["git", "-C", str(ROOT), "archive", rev], check=True, capture_output=True
        ).stdout
        subprocess.run(["tar", "-x", "-C", tmp], input=archive, check=True)
        yield Path(tmp)


@contextlib.contextmanager
def daemon_of(tree: Path, env: dict[str, str] | None = None) -> Iterator[DaemonProcess]:
    """The EMULATED cell (:data:`SIM`) and ``cablecal serve`` of source ``tree`` as real
    processes on loopback (``env``: the daemon's extra environment)."""
    here = Path.cwd()
    os.chdir(tree)  # `python -m daemon` imports from the working directory first
    try:
        with tempfile.TemporaryDirectory(prefix="cablecal-bench-") as tmp:
            daemon_env = {"PYTHONPATH": str(tree), "CABLECAL_SAMPLER__SETTLE_S": "0.3"}
            with Cell(Path(tmp), SIM, daemon_env={**daemon_env, **(env or {})}) as cell:
                assert cell.daemon is not None
                yield cell.daemon
    finally:
        os.chdir(here)


def rss_kib(pid: int) -> int:
    """VmRSS of ``pid`` [KiB], 0 when gone."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    except OSError:
        pass
    return 0


def descendants(pid: int) -> list[int]:
    """Pids of every process below ``pid`` (its children, theirs, ...)."""
    parent: dict[int, int] = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            with contextlib.suppress(OSError, IndexError, ValueError):
                stat = Path(f"/proc/{entry}/stat").read_text()
                parent[int(entry)] = int(stat.rsplit(")", 1)[1].split()[1])
    out, frontier = [], [pid]
    while frontier:
        p = frontier.pop()
        kids = [c for c, pp in parent.items() if pp == p]
        out += kids
        frontier += kids
    return out


class Watch:
    """/health latency at 20 Hz and RSS every 0.25 s, in threads, while a phase runs."""

    def __init__(self, url: str, pid: int) -> None:
        self.url, self.pid = url, pid
        self.health_s: list[float] = []
        self.rss_daemon_kib = 0
        self.rss_all_kib = 0
        self._stop = threading.Event()
        self._threads = [threading.Thread(target=f, daemon=True) for f in (self._h, self._m)]

    def _h(self) -> None:
        with httpx.Client(timeout=HEALTH_TIMEOUT_S) as c:
            while not self._stop.wait(HEALTH_INTERVAL_S):
                t0 = time.monotonic()
                try:
                    c.get(self.url + "/api/v1/health").raise_for_status()
                    self.health_s.append(time.monotonic() - t0)
                except httpx.HTTPError:
                    self.health_s.append(HEALTH_TIMEOUT_S)

    def _m(self) -> None:
        while not self._stop.wait(0.25):
            own = rss_kib(self.pid)
            self.rss_daemon_kib = max(self.rss_daemon_kib, own)
            total = own + sum(rss_kib(p) for p in descendants(self.pid))
            self.rss_all_kib = max(self.rss_all_kib, total)

    def __enter__(self) -> Watch:
        for t in self._threads:
            t.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        for t in self._threads:
            t.join()

    def summary(self) -> dict[str, Any]:
        h = sorted(self.health_s) or [float("nan")]

        def q(f: float) -> float:
            return round(1000 * h[min(len(h) - 1, int(f * len(h)))], 1)

        return {
            "health_n": len(self.health_s),
            "health_p50_ms": q(0.5),
            "health_p99_ms": q(0.99),
            "health_max_ms": round(1000 * h[-1], 1),
            "rss_daemon_mib": round(self.rss_daemon_kib / 1024, 1),
            "rss_with_children_mib": round(self.rss_all_kib / 1024, 1),
        }


def phase(url: str, pid: int, seconds: float, attack: Any = None) -> dict[str, Any]:
    """Poll rate, ``/health`` and RSS over ``attack(deadline)`` (its counts merged in), or
    over ``seconds`` of idle."""
    with Watch(url, pid) as watch:

        def work() -> dict[str, Any]:
            if attack is None:
                time.sleep(seconds)
                return {}
            counts: dict[str, Any] = attack(time.monotonic() + seconds)
            return counts

        rate, counts = poll_rate(url, work)
    return {**rate, **watch.summary(), **counts}
