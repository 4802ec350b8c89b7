"""API latency under load while the sampler runs, and the daemon's memory.

Starts the emulated cell and ``cablecal serve`` as real processes (auto capture on, so the
sampler polls and stores), then a SECOND process sends ``GET /api/v1/status`` open-loop at
200 req/s for 20 s and records each latency. In the same run and the same way it measures
``GET /api/v1/health`` (a route that does nothing) as the baseline, so the table shows what the
status route itself costs. Targets (issue 4): p99 of /status < 20 ms; daemon RSS < 150 MB.

Run: ``python -m bench.api_bench`` (``make bench`` calls it). Writes bench/api_results.json and
bench/api_results.md.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from calib.default_robot import DEFAULT_ROBOT_MODEL
from daemon.cli.emulated import Cell

OUT = Path(__file__).resolve().parent
RATE_HZ = 200.0
DURATION_S = 20.0

SIM = """
seed = 5
[robot]
n_poses = 400
move_time_s = 0.5
dwell_s = 1.0
[indicator]
baud = {baud}
[robot_socketcmd]
port = 0
[robot_modbus]
port = 0
"""

#: The load generator, run as its own process: open-loop GETs at a fixed rate over a pool of
#: keep-alive HTTP/1.1 connections (raw asyncio streams: a Python HTTP client library would
#: cost more CPU than the server it measures on a 2-core machine). Latency is taken from the
#: scheduled send time, so queueing in the client counts too (no coordinated omission).
#:
#: A pooled connection idle for more than ``idle_max_s`` is closed, not reused: uvicorn closes
#: a keep-alive connection after 5 s idle (``timeout_keep_alive``), and a request written to it
#: then reads EOF (``IncompleteReadError``), an error of the generator, not of the service.
#: (After a latency spike the pool holds more connections than the steady rate needs; the
#: deepest ones idle until the next spike.) Every error is counted by kind: ``HTTP <status>``
#: for an answer other than 200, else the exception's class name.
LOADGEN = r"""
import asyncio, collections, json, sys, time

async def main(host, port, path, token, rate, duration, idle_max_s):
    req = (f"GET {path} HTTP/1.1\r\nHost: {host}\r\nAuthorization: Bearer {token}\r\n\r\n").encode()
    idle = []  # (reader, writer, last used [perf_counter s]), most recently used last
    lat, kinds = [], collections.Counter()

    async def connection():
        while idle:
            reader, writer, t_used = idle.pop()
            if time.perf_counter() - t_used <= idle_max_s:
                return reader, writer
            writer.close()
        return await asyncio.open_connection(host, port)

    async def one(t_sched):
        writer = None
        try:
            reader, writer = await connection()
            writer.write(req)
            head = await reader.readuntil(b"\r\n\r\n")
            status = int(head.split(b" ", 2)[1])
            length = 0
            for line in head.split(b"\r\n"):
                if line.lower().startswith(b"content-length:"):
                    length = int(line.split(b":", 1)[1])
            await reader.readexactly(length)
            if status != 200:
                kinds[f"HTTP {status}"] += 1
            idle.append((reader, writer, time.perf_counter()))
        except (OSError, asyncio.IncompleteReadError, asyncio.LimitOverrunError, ValueError) as exc:
            kinds[type(exc).__name__] += 1
            if writer is not None:
                writer.close()
        lat.append(time.perf_counter() - t_sched)

    tasks = []
    start = time.perf_counter()
    for i in range(int(rate * duration)):
        t_sched = start + i / rate
        delay = t_sched - time.perf_counter()
        if delay > 0:
            await asyncio.sleep(delay)
        tasks.append(asyncio.create_task(one(t_sched)))
    await asyncio.gather(*tasks)
    elapsed = time.perf_counter() - start
    print(json.dumps({"latencies_s": lat, "errors": sum(kinds.values()),
                      "error_kinds": dict(kinds), "elapsed_s": elapsed}))

host, port, path, token, rate, duration, idle_max_s = sys.argv[1:8]
asyncio.run(main(host, int(port), path, token, float(rate), float(duration), float(idle_max_s)))
"""

#: Close pooled connections idle longer than this [s] (uvicorn closes them at 5 s).
KEEPALIVE_IDLE_MAX_S = 4.0


def _rss_mb(pid: int) -> dict[str, float]:
    out: dict[str, float] = {}
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(("VmRSS:", "VmHWM:")):
            key, value = line.split(":", 1)
            out[key] = float(value.split()[0]) / 1024.0
    return out


def _load(
    url: str,
    token: str,
    rate_hz: float,
    duration_s: float,
    idle_max_s: float = KEEPALIVE_IDLE_MAX_S,
) -> dict[str, Any]:
    """GET ``url`` open-loop at ``rate_hz`` for ``duration_s`` (the :data:`LOADGEN` process);
    pooled connections idle longer than ``idle_max_s`` are closed, not reused. Returns the
    request count, errors (and ``error_kinds``: count per kind), achieved rate and latency
    percentiles [ms]."""
    rest = url.split("://", 1)[1]
    hostport, path = rest.split("/", 1)
    host, port = hostport.rsplit(":", 1)
    proc = subprocess.run(
        [
            sys.executable,
            "-c",
            LOADGEN,
            host,
            port,
            "/" + path,
            token,
            str(rate_hz),
            str(duration_s),
            str(idle_max_s),
        ],
        capture_output=True,
        text=True,
        timeout=duration_s + 60,
        check=True,
    )
    data = json.loads(proc.stdout)
    lat_ms = np.asarray(data["latencies_s"]) * 1e3
    return {
        "requests": int(lat_ms.size),
        "errors": int(data["errors"]),
        "error_kinds": dict(sorted(data["error_kinds"].items())),
        "achieved_rate_hz": round(lat_ms.size / data["elapsed_s"], 1),
        "p50_ms": round(float(np.percentile(lat_ms, 50)), 2),
        "p99_ms": round(float(np.percentile(lat_ms, 99)), 2),
        "max_ms": round(float(lat_ms.max()), 2),
    }


def errors_text(load: dict[str, Any]) -> str:
    """The errors of a :func:`_load` result with their kinds, e.g. ``1 (HTTP 500: 1)``."""
    kinds = ", ".join(f"{k}: {n}" for k, n in load.get("error_kinds", {}).items())
    return f"{load['errors']} ({kinds})" if kinds else str(load["errors"])


def run(
    rate_hz: float = RATE_HZ, duration_s: float = DURATION_S, baud: int = 9600
) -> dict[str, Any]:
    """Measure and write bench/api_results.{json,md}; returns the results.

    ``baud``: the indicator link; 9600 is the HY9648's default (the sampler then polls at
    about 26 Hz), 115200 makes it poll about six times as often.
    """
    with tempfile.TemporaryDirectory(prefix="cablecal-apibench-") as tmp:
        env = {"CABLECAL_INDICATOR__BAUD": str(baud), "CABLECAL_SAMPLER__SETTLE_S": "0.3"}
        with Cell(Path(tmp), SIM.format(baud=baud), daemon_env=env) as cell:
            assert cell.daemon is not None
            api = cell.daemon.client()
            cid = api.post("/campaigns", json={"name": "bench", "robot_model": DEFAULT_ROBOT_MODEL})
            campaign_id = cid.json()["id"]
            api.put(f"/campaigns/{campaign_id}/auto-capture", json={"enabled": True})
            time.sleep(3.0)
            base = cell.daemon.url + "/api/v1"
            health = _load(base + "/health", cell.token, rate_hz, duration_s)
            status = _load(base + "/status", cell.token, rate_hz, duration_s)
            n_samples = len(api.get(f"/campaigns/{campaign_id}/samples").json())
            rss = _rss_mb(cell.daemon.popen.pid)
            polls = api.get("/status").json()["devices"]["indicator"]["poll_rate_hz"]
    results = {
        "indicator_baud": baud,
        "load_average_1min": round(os.getloadavg()[0], 2),
        "rate_hz": rate_hz,
        "duration_s": duration_s,
        "status": status,
        "baseline_health": health,
        "captures_during_run": n_samples,
        "indicator_poll_rate_hz_at_end": polls,
        "daemon_rss_mb": round(rss.get("VmRSS", float("nan")), 1),
        "daemon_peak_rss_mb": round(rss.get("VmHWM", float("nan")), 1),
        "targets": {"status_p99_ms": 20.0, "rss_mb": 150.0},
        "met": {
            "status_p99": status["p99_ms"] < 20.0,
            "rss": rss.get("VmHWM", 1e9) < 150.0,
        },
    }
    (OUT / "api_results.json").write_text(json.dumps(results, indent=2) + "\n")
    md = [
        f"# API latency under load ({rate_hz:.0f} req/s for {duration_s:.0f} s, sampler running "
        f"at {baud} baud)",
        "",
        "| route | requests | errors (kinds) | achieved req/s | p50 ms | p99 ms | max ms |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, r in (("GET /api/v1/status", status), ("GET /api/v1/health (baseline)", health)):
        md.append(
            f"| {name} | {r['requests']} | {errors_text(r)} | {r['achieved_rate_hz']} | "
            f"{r['p50_ms']} | {r['p99_ms']} | {r['max_ms']} |"
        )
    md += [
        "",
        f"Daemon RSS {results['daemon_rss_mb']} MB (peak {results['daemon_peak_rss_mb']} MB; "
        "the identification pool's worker processes are separate and not included). "
        f"Captures stored during the run: {n_samples}; indicator polled at {polls} Hz. "
        f"Machine load average (1 min) at the end: {results['load_average_1min']} on "
        f"{os.cpu_count()} cores. Targets: /status p99 < 20 ms "
        f"({'met' if results['met']['status_p99'] else 'NOT met'}), RSS < 150 MB "
        f"({'met' if results['met']['rss'] else 'NOT met'}).",
        "",
    ]
    (OUT / "api_results.md").write_text("\n".join(md))
    return results


if __name__ == "__main__":
    print(json.dumps(run(), indent=2))
