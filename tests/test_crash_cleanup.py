"""A SIGKILLed daemon leaves no process behind, and its next start records the unclean stop.

The real ``cablecal serve`` runs without devices (an unplugged indicator, the manual robot),
as in tests/test_daemon_systemd.py. The daemon's descendants (forkserver, pool workers, manager,
resource tracker) are found in /proc by parent pid before the kill, then watched by pid.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import httpx
import pytest

from daemon.cli.emulated import Process, wait_for
from daemon.datafiles import bundled_dataset_text

pytestmark = [pytest.mark.slow, pytest.mark.timeout(240)]

#: How long the children may outlive the daemon [s] (issue 11).
CLEANUP_LIMIT_S = 2.0
TOKEN = "crash-cleanup-test-token"  # the config needs at least 16 characters


def proc_stat(pid: int) -> list[str] | None:
    """Fields of /proc/PID/stat from field 3 (state) on, or None if the process is gone."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except (FileNotFoundError, ProcessLookupError):
        return None
    return text.rsplit(")", 1)[1].split()


def alive(pid: int) -> bool:
    """The process exists and is not a zombie."""
    fields = proc_stat(pid)
    return fields is not None and fields[0] != "Z"


def descendants(root: int) -> dict[int, str]:
    """Live descendants of ``root`` (not ``root`` itself): pid → command line."""
    parent: dict[int, int] = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit() and (fields := proc_stat(int(entry))) is not None and fields[0] != "Z":
            parent[int(entry)] = int(fields[1])
    found: dict[int, str] = {}
    frontier = {root}
    while frontier:
        frontier = {pid for pid, ppid in parent.items() if ppid in frontier} - found.keys()
        for pid in frontier:
            try:
                cmd = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
            except OSError:
                cmd = "?"
            found[pid] = cmd.strip()
    return found


def kill_all(pids: Iterable[int]) -> None:
    """SIGKILL what a failed test left behind."""
    for pid in pids:
        if alive(pid):
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)


def short_name(cmdline: str, of_daemon: bool) -> str:
    """``forkserver``, ``resource_tracker``, or ``child PID`` (forked by the forkserver: a pool
    worker or the manager, which carry the forkserver's command line)."""
    if "multiprocessing.resource_tracker import main" in cmdline:
        return "resource_tracker"
    if of_daemon:
        return "forkserver"
    return "child"


def niceness(pid: int) -> int:
    fields = proc_stat(pid)
    assert fields is not None, pid
    return int(fields[16])  # field 19 of /proc/PID/stat


def start_daemon(tmp_path: Path) -> tuple[Process, str]:
    env = {
        "CABLECAL_STATE_DIR": str(tmp_path),
        "CABLECAL_API_TOKEN": TOKEN,
        "CABLECAL_INDICATOR__PORT": str(tmp_path / "no-such-adapter"),
        "CABLECAL_LOG_JSON": "true",
    }
    proc = Process(
        [sys.executable, "-m", "daemon", "serve", "--port", "0"], tmp_path / "daemon.log", env
    )
    serving = json.loads(proc.wait_line("SERVING ", timeout_s=90))
    return proc, str(serving["url"]) + "/api/v1"


def api_client(url: str) -> httpx.Client:
    return httpx.Client(base_url=url, headers={"Authorization": f"Bearer {TOKEN}"}, timeout=30)


def start_long_de_job(api: httpx.Client) -> int:
    r = api.post("/campaigns", json={"name": "crash", "robot_model": "hsr-jr680"})
    assert r.status_code == 201, r.text
    cid = int(r.json()["id"])
    csv = bundled_dataset_text()
    r = api.post(
        f"/campaigns/{cid}/samples/import", content=csv, headers={"Content-Type": "text/csv"}
    )
    assert r.status_code == 201, r.text
    r = api.post(
        f"/campaigns/{cid}/identifications",
        json={"method": "de", "seed": 0},
    )
    assert r.status_code == 202, r.text
    return int(r.json()["id"])


def start_running_de_job(api: httpx.Client) -> int:
    """:func:`start_long_de_job`, once a worker runs it."""
    job_id = start_long_de_job(api)
    wait_for(
        lambda: api.get(f"/identifications/{job_id}").json()["status"] == "running",
        60,
        0.2,
        "the DE job to run",
    )
    return job_id


def events(api: httpx.Client, kind: str) -> list[dict[str, Any]]:
    r = api.get("/events", params={"kind": kind, "limit": 100})
    r.raise_for_status()
    return list(r.json())


def test_sigkill_leaves_no_child_and_the_restart_records_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    proc, url = start_daemon(tmp_path)
    daemon_pid = proc.popen.pid
    children: dict[int, str] = {}
    try:
        api = api_client(url)
        assert events(api, "unclean_shutdown") == []
        started = events(api, "daemon_started")
        assert [e["detail"]["pid"] for e in started] == [daemon_pid]
        job_id = start_running_de_job(api)
        children = descendants(daemon_pid)
        # forkserver, pool worker, manager, resource tracker
        assert len(children) >= 4, children
        workers = [p for p in children if niceness(p) == 10]
        assert len(workers) >= 2, {p: niceness(p) for p in children}  # pool worker and manager
        # Each in a session (a scheduling autogroup) of its own, not the daemon's.
        assert all(int((proc_stat(p) or ["0"] * 4)[3]) == p for p in workers)
        # The worker computes: its CPU time grows.
        cpu = {p: sum(map(int, (proc_stat(p) or ["0"] * 14)[11:13])) for p in workers}
        time.sleep(1.0)
        assert any(sum(map(int, (proc_stat(p) or ["0"] * 14)[11:13])) > cpu[p] for p in workers)

        names = {
            p: short_name(c, int((proc_stat(p) or ["", "0"])[1]) == daemon_pid)
            for p, c in children.items()
        }
        t_kill = time.monotonic()
        os.kill(daemon_pid, signal.SIGKILL)
        left = children
        gone_s: dict[str, float] = {}
        while left and time.monotonic() - t_kill < 10.0:
            time.sleep(0.02)
            for p in [p for p in left if not alive(p)]:
                gone_s[f"{names[p]} {p}"] = round(time.monotonic() - t_kill, 2)
            left = {p: c for p, c in left.items() if alive(p)}
        gone_after_s = time.monotonic() - t_kill
        proc.popen.wait(timeout=5)
        with capsys.disabled():
            print(
                f"\ncrash clean-up: {len(children)} children of the SIGKILLed daemon gone after "
                f"{gone_after_s:.2f} s (limit {CLEANUP_LIMIT_S} s): {gone_s}"
            )
        assert not left, f"still alive {gone_after_s:.1f} s after SIGKILL: {left}"
        assert gone_after_s < CLEANUP_LIMIT_S
        # Issue 21: the forkserver's children (pool workers, manager) are reaped by the
        # forkserver itself, not left defunct for init: gone from /proc, not zombies.
        pool_children = [p for p in children if names[p] == "child"]
        assert pool_children, names
        defunct = [p for p in pool_children if proc_stat(p) is not None]
        assert not defunct, {p: proc_stat(p) for p in defunct}
    finally:
        proc.stop()
        kill_all(children)

    # The restart records the unclean stop, naming the killed run's start and pid.
    proc, url = start_daemon(tmp_path)
    try:
        api = api_client(url)
        unclean = events(api, "unclean_shutdown")
        assert len(unclean) == 1, unclean
        detail = unclean[0]["detail"]
        assert detail["previous_pid"] == daemon_pid
        assert detail["previous_started_at"] == started[0]["t_wall"]
        assert str(daemon_pid) in unclean[0]["message"]
        # The interrupted job is marked failed by the restart.
        job = api.get(f"/identifications/{job_id}").json()
        assert job["status"] == "failed", job
    finally:
        code = proc.stop()
    assert code in (0, -15), proc.log_tail()

    # After a clean stop, the next start records nothing unclean.
    proc, url = start_daemon(tmp_path)
    try:
        api = api_client(url)
        assert len(events(api, "unclean_shutdown")) == 1
        assert len(events(api, "daemon_started")) == 3
    finally:
        proc.stop()


def test_children_exit_when_a_plain_parent_is_killed(tmp_path: Path) -> None:
    """The mechanism alone, without the daemon: a parent with a forkserver pool whose workers
    run :func:`daemon.process.workers.init_child`; SIGKILL the parent mid-job."""
    script = tmp_path / "parent.py"
    script.write_text(
        """
import json, multiprocessing, sys, time
from concurrent.futures import ProcessPoolExecutor
from daemon.process.workers import child_state, init_child

def busy() -> None:
    while True:
        sum(range(10_000))

if __name__ == "__main__":
    ctx = multiprocessing.get_context("forkserver")
    pool = ProcessPoolExecutor(2, mp_context=ctx, initializer=init_child, initargs=(5, 1))
    states = [pool.submit(child_state).result() for _ in range(2)]
    print("STATE", json.dumps(states), flush=True)
    pool.submit(busy)
    pool.submit(busy)
    time.sleep(600)
""",
        encoding="utf-8",
    )
    popen = subprocess.Popen(
        [sys.executable, str(script)],
        stdout=subprocess.PIPE,
        text=True,
        start_new_session=True,
        cwd=Path(__file__).resolve().parents[1],
    )
    children: set[int] = set()
    try:
        assert popen.stdout is not None
        line = popen.stdout.readline()
        assert line.startswith("STATE"), line
        state = json.loads(line[len("STATE") :])
        assert all(s["nice"] >= 5 and s["watchdog"] for s in state), state
        assert all(s["session"] == s["pid"] for s in state), state
        assert all(n == 1 for s in state for n in s["threads"].values()), state
        time.sleep(0.5)
        children = set(descendants(popen.pid))
        assert len(children) >= 3, children  # forkserver, 2 workers (and the tracker)
        t_kill = time.monotonic()
        popen.kill()
        popen.wait(5)
        while children and time.monotonic() - t_kill < 10:
            time.sleep(0.02)
            children = {p for p in children if alive(p)}
        assert not children, children
        assert time.monotonic() - t_kill < CLEANUP_LIMIT_S
    finally:
        if popen.poll() is None:
            popen.kill()
            popen.wait(5)
        kill_all(children)


def test_a_sigkilled_worker_is_reaped_and_the_next_job_runs(tmp_path: Path) -> None:
    """Issue 21: SIGKILL the pool worker running a job. It is reaped at once (not defunct),
    the job is marked failed saying why, and the next job gets a new pool and runs."""
    from daemon.jobs.manager import WORKER_DIED

    proc, url = start_daemon(tmp_path)
    try:
        api = api_client(url)
        job_id = start_running_de_job(api)
        children = descendants(proc.popen.pid)
        pool = [
            p
            for p, c in children.items()
            if short_name(c, False) != "resource_tracker"
            and int((proc_stat(p) or ["", "0"])[1]) != proc.popen.pid
        ]

        def ticks(p: int) -> int:
            return sum(map(int, (proc_stat(p) or ["0"] * 14)[11:13]))

        # The worker running the DE job is the one that burns CPU. Another pool process may
        # still be starting (imports) at first: measure over a second, after a settling one,
        # and take the busiest.
        time.sleep(1.0)
        cpu = {p: ticks(p) for p in pool}
        time.sleep(1.0)
        delta = {p: ticks(p) - cpu[p] for p in pool}
        worker = max(delta, key=lambda p: delta[p])
        assert delta[worker] > 0, (pool, delta)
        t_kill = time.monotonic()
        os.kill(worker, signal.SIGKILL)
        while proc_stat(worker) is not None and time.monotonic() - t_kill < 10:
            time.sleep(0.02)
        gone_s = time.monotonic() - t_kill
        assert proc_stat(worker) is None, f"worker {worker} still in /proc: {proc_stat(worker)}"
        assert gone_s < CLEANUP_LIMIT_S, gone_s
        wait_for(
            lambda: api.get(f"/identifications/{job_id}").json()["status"] == "failed",
            10,
            0.1,
            "the killed job to be marked failed",
        )
        assert api.get(f"/identifications/{job_id}").json()["error"] == WORKER_DIED
        cid = api.get(f"/identifications/{job_id}").json()["campaign_id"]
        r = api.post(f"/campaigns/{cid}/identifications", json={"method": "lm"})
        assert r.status_code == 202, r.text
        nxt = int(r.json()["id"])
        wait_for(
            lambda: api.get(f"/identifications/{nxt}").json()["status"] in ("running", "succeeded"),
            60,
            0.1,
            "the next job to run on a new pool",
        )
    finally:
        proc.stop()
