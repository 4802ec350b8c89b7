"""The indicator poll rate while identification jobs run, against idle (issue 11).

Starts the EMULATED cell and ``cablecal serve`` as real processes (indicator at 9600 baud, the
HY9648's default, where the sampler polls at about 26 Hz), imports the bundled dataset (2017
samples) into a campaign, and measures the indicator poll rate from the daemon's
``cablecal_device_polls_total`` counter (polls over wall time) in three phases of the same run:
idle, busy (identification jobs back to back, each submitted when the previous one finished),
idle again. The ratio is busy over the mean of the two idle phases, so a change of the
machine's load during the run shows as a difference between the idle phases. It also samples
``GET /status`` at 5 Hz and counts how often the settle state was ``stale`` (a gap between
readings longer than ``stale_s``).

It does this twice: with the daemon's worker settings (``jobs.worker_nice`` 10, one BLAS
thread per worker) and, as the "before", with ``worker_nice = 0`` and as many BLAS threads as
cores. Target: busy >= 95 % of idle with the daemon's settings.

Run: ``python -m bench.sampler_priority`` (``make bench`` calls it; about 4 minutes). Writes
bench/sampler_priority.json and bench/sampler_priority.md.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import httpx

from bench.cellrun import SIM, poll_rate
from calib.default_robot import DEFAULT_ROBOT_MODEL
from daemon.cli.emulated import Cell, wait_for
from daemon.datafiles import bundled_dataset_text

OUT = Path(__file__).resolve().parent
TARGET_RATIO = 0.95
PHASE_S = 25.0
METHOD = "ukf-vslm"
STATUS_INTERVAL_S = 0.2

#: Worker settings per configuration: the daemon's defaults, and none (before issue 11).
CONFIGS: dict[str, dict[str, str]] = {
    "worker_nice=10, 1 BLAS thread (default)": {},
    "worker_nice=0, BLAS threads = cores (before)": {
        "CABLECAL_JOBS__WORKER_NICE": "0",
        "CABLECAL_JOBS__WORKER_BLAS_THREADS": str(os.cpu_count() or 1),
    },
}


class StatusSampler:
    """Reads ``GET /status`` every :data:`STATUS_INTERVAL_S` in a thread; counts settle
    states."""

    def __init__(self, api: httpx.Client) -> None:
        self.api = api
        self.states: list[str] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self._stop.wait(STATUS_INTERVAL_S):
            try:
                st = self.api.get("/status").json()["sampler"]
            except (httpx.HTTPError, KeyError, ValueError):
                continue
            self.states.append(str(st.get("settle_state")))

    def __enter__(self) -> StatusSampler:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()

    def stale_fraction(self) -> float:
        return sum(s == "stale" for s in self.states) / max(len(self.states), 1)


def measure(url: str, api: httpx.Client, seconds: float, busy: Any = None) -> dict[str, Any]:
    """Poll rate over ``seconds`` (plus the end of the last job when ``busy`` runs jobs)."""
    with StatusSampler(api) as status:
        rate, jobs = poll_rate(
            url,
            lambda: busy(time.monotonic() + seconds) if busy is not None else time.sleep(seconds),
        )
    out: dict[str, Any] = {**rate, "stale_fraction": round(status.stale_fraction(), 4)}
    if jobs is not None:
        out["jobs"] = jobs
    return out


def finished(api: httpx.Client, job_id: int) -> dict[str, Any] | None:
    """The job once it has finished, else None."""
    job: dict[str, Any] = api.get(f"/identifications/{job_id}").json()
    return job if job["status"] in ("succeeded", "failed", "cancelled") else None


def jobs_back_to_back(api: httpx.Client, campaign_id: int) -> Any:
    """A ``busy`` function for :func:`measure`: identification jobs back to back until the
    deadline; returns the count and durations."""

    def run(deadline: float) -> dict[str, Any]:
        durations: list[float] = []
        while time.monotonic() < deadline:
            t0 = time.monotonic()
            r = api.post(f"/campaigns/{campaign_id}/identifications", json={"method": METHOD})
            r.raise_for_status()
            job_id = r.json()["id"]
            job = wait_for(lambda jid=job_id: finished(api, jid), 600, 0.25, f"job {job_id}")
            if job["status"] != "succeeded":
                raise RuntimeError(f"job {job_id}: {job['status']}: {job.get('error')}")
            durations.append(round(time.monotonic() - t0, 2))
        return {"method": METHOD, "count": len(durations), "durations_s": durations}

    return run


def run_config(env: dict[str, str], phase_s: float) -> dict[str, Any]:
    """Idle, busy, idle for one worker configuration."""
    with tempfile.TemporaryDirectory(prefix="cablecal-priobench-") as tmp:
        daemon_env = {"CABLECAL_SAMPLER__SETTLE_S": "0.3", **env}
        with Cell(Path(tmp), SIM, daemon_env=daemon_env) as cell:
            assert cell.daemon is not None
            url = cell.daemon.url
            api = cell.daemon.client()
            r = api.post("/campaigns", json={"name": "bench", "robot_model": DEFAULT_ROBOT_MODEL})
            r.raise_for_status()
            cid = int(r.json()["id"])
            r = api.post(
                f"/campaigns/{cid}/samples/import",
                content=bundled_dataset_text(),
                headers={"Content-Type": "text/csv"},
            )
            r.raise_for_status()
            time.sleep(3.0)  # the links settle after start-up
            idle_before = measure(url, api, phase_s)
            busy = measure(url, api, phase_s, jobs_back_to_back(api, cid))
            idle_after = measure(url, api, phase_s)
    idle_hz = (idle_before["poll_rate_hz"] + idle_after["poll_rate_hz"]) / 2
    return {
        "env": env,
        "idle_before": idle_before,
        "busy": busy,
        "idle_after": idle_after,
        "idle_mean_poll_rate_hz": round(idle_hz, 3),
        "busy_over_idle": round(busy["poll_rate_hz"] / idle_hz, 4),
    }


def markdown(results: dict[str, Any]) -> str:
    lines = [
        "# Indicator poll rate while identification jobs run",
        "",
        f"Emulated cell, indicator at 9600 baud; `{METHOD}` jobs on the bundled dataset "
        f"(2017 samples) back to back; phases of {results['phase_s']:.0f} s in one run "
        f"(idle, busy, idle); {os.cpu_count()} cores, shared with other work (load average "
        "per phase below). Rate: the daemon's indicator poll counter over wall time. "
        "*stale*: share of `GET /status` samples (5 Hz) whose settle state was `stale`.",
        "",
        "| workers | idle before [Hz] | busy [Hz] | idle after [Hz] | busy / idle | jobs | "
        "job time [s] | stale idle / busy | load (idle, busy, idle) |",
        "|---|---:|---:|---:|---:|---:|---|---|---|",
    ]
    for name, r in results["configs"].items():
        ib, b, ia = r["idle_before"], r["busy"], r["idle_after"]
        lines.append(
            f"| {name} | {ib['poll_rate_hz']:.2f} | {b['poll_rate_hz']:.2f} | "
            f"{ia['poll_rate_hz']:.2f} | {100 * r['busy_over_idle']:.1f} % | "
            f"{b['jobs']['count']} | {', '.join(map(str, b['jobs']['durations_s']))} | "
            f"{100 * ib['stale_fraction']:.1f} % / "
            f"{100 * b['stale_fraction']:.1f} % | {ib['load_average_1min']}, "
            f"{b['load_average_1min']}, {ia['load_average_1min']} |"
        )
    met = results["met"]
    lines += [
        "",
        f"Target: busy >= {100 * TARGET_RATIO:.0f} % of idle with the default worker settings: "
        f"{'met' if met else 'NOT met'}. The price: on a machine busy with other work, a job "
        "at low priority takes longer (*job time*); on an otherwise idle cell PC the workers "
        "get the idle cores anyway.",
        "",
    ]
    return "\n".join(lines)


def run(phase_s: float = PHASE_S, only_default: bool = False) -> dict[str, Any]:
    """Measure every configuration, write bench/sampler_priority.{json,md}; returns them."""
    names = list(CONFIGS)[:1] if only_default else list(CONFIGS)
    configs = {name: run_config(CONFIGS[name], phase_s) for name in names}
    default = configs[names[0]]
    results = {
        "phase_s": phase_s,
        "cpus": os.cpu_count(),
        "target_busy_over_idle": TARGET_RATIO,
        "configs": configs,
        "met": default["busy_over_idle"] >= TARGET_RATIO,
    }
    (OUT / "sampler_priority.json").write_text(json.dumps(results, indent=2) + "\n")
    (OUT / "sampler_priority.md").write_text(markdown(results))
    return results


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--phase-s", type=float, default=PHASE_S, help="seconds per phase")
    parser.add_argument(
        "--only-default", action="store_true", help="skip the 'before' configuration"
    )
    args = parser.parse_args(argv)
    results = run(args.phase_s, args.only_default)
    print(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()
