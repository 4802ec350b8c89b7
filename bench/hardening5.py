"""The sampler under issue 31's attacks, before and after, in one run (loopback only).

For each tree (``before``: a git revision unpacked with ``git archive`` into a temporary
directory; ``after``: this working tree) it starts the EMULATED cell and ``cablecal serve``
from that tree as real processes (indicator at 9600 baud, where the sampler polls at about
26 Hz), imports the bundled dataset (2017 samples), identifies and accepts it (the filter
route needs a calibration), creates ``CAMPAIGNS`` campaigns with the longest notes (so a list
page is large), then measures two phases of ``PHASE_S`` seconds each:

- **idle**: nothing but the measurement;
- **attack**: six clients posting crafted 300 KiB multipart uploads to
  ``POST /robots/{id}/filter`` back to back (16,000 RFC 2231 ``filename*N`` parameters in one
  part, the issue's quadratic case), and five slow readers that ask for the largest page of
  ``GET /campaigns`` the tree allows and read none of it (re-connecting when cut).

Measured per phase: the indicator poll rate (the daemon's ``cablecal_device_polls_total``
over wall time), ``GET /health`` latency sampled at 20 Hz (p50, p99, max; a timeout counts as
5 s), the largest RSS of the daemon and of the daemon with its children (``/proc``, every
0.25 s), and the status of every attack request. Every loop is bounded by the phase's time.

Run: ``python -m bench.hardening5 [--before REV] [--phase-s S]`` (about 4 minutes). Writes
bench/hardening5.json and bench/hardening5.md.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import socket
import subprocess
import tempfile
import threading
import time
from collections import Counter
from pathlib import Path
from typing import Any

import httpx

from bench.sampler_priority import indicator_polls
from calib.default_robot import DEFAULT_ROBOT_MODEL
from daemon.cli.emulated import Cell, wait_for
from daemon.datafiles import bundled_dataset_text

OUT = Path(__file__).resolve().parent
ROOT = OUT.parent
#: The revision before issue 31's items 2-8 (the base of this work).
BEFORE_REV = "fad0e1d"
PHASE_S = 20.0
CAMPAIGNS = 600
NOTES = '"' * 10_000  # 20 kB each as JSON
UPLOADERS = 6
#: Seconds between the starts of one client's uploads (0: back to back); ``--flood`` sets 0.
UPLOAD_PERIOD_S = 1.0
SLOW_READERS = 5
HEALTH_INTERVAL_S = 0.05
HEALTH_TIMEOUT_S = 5.0
BOUNDARY = "b0undary"

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


def crafted_upload() -> bytes:
    """A 300 KiB multipart body: one part whose Content-Disposition carries 16,000 RFC 2231
    ``filename*N`` continuations (quadratic in the standard library's email parser)."""
    params = "".join(f"; filename*{k}=x" for k in range(16_000))
    head = f'--{BOUNDARY}\r\nContent-Disposition: form-data; name="files"{params}\r\n\r\n'
    return (head + "MODULE M\nENDMODULE\n\r\n" + f"--{BOUNDARY}--\r\n").encode()


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


def uploader(
    url: str, token: str, rid: int, body: bytes, deadline: float, out: Counter[str]
) -> None:
    headers = {
        "Authorization": f"Bearer {token}",
        "Content-Type": f"multipart/form-data; boundary={BOUNDARY}",
    }
    with httpx.Client(timeout=30) as c:
        while time.monotonic() < deadline:
            t0 = time.monotonic()
            try:
                r = c.post(f"{url}/api/v1/robots/{rid}/filter", content=body, headers=headers)
                out[str(r.status_code)] += 1
            except httpx.HTTPError as exc:
                out[type(exc).__name__] += 1
            time.sleep(max(0.0, min(UPLOAD_PERIOD_S - (time.monotonic() - t0), deadline - t0)))


def slow_reader(
    addr: tuple[str, int], token: str, page: int, deadline: float, out: Counter[str]
) -> None:
    request = (
        f"GET /api/v1/campaigns?limit={page} HTTP/1.1\r\nHost: x\r\n"
        f"Authorization: Bearer {token}\r\n\r\n"
    ).encode()
    while time.monotonic() < deadline:
        s = socket.socket()
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        try:
            s.connect(addr)
            s.sendall(request)
            out["connections"] += 1
            # Read nothing; a cut connection shows as readable with EOF or a reset.
            while time.monotonic() < deadline:
                time.sleep(0.5)
                with contextlib.suppress(OSError):
                    s.setblocking(False)
                    try:
                        if s.recv(1, socket.MSG_PEEK) == b"":
                            out["cut"] += 1
                            break
                    except BlockingIOError:
                        pass
                    except ConnectionResetError:
                        out["cut"] += 1
                        break
        except OSError:
            out["refused"] += 1
            time.sleep(0.5)
        finally:
            s.close()


def phase(url: str, pid: int, seconds: float, attack: Any = None) -> dict[str, Any]:
    with Watch(url, pid) as watch:
        polls0, t0 = indicator_polls(url), time.monotonic()
        counts: dict[str, Any] = attack(t0 + seconds) if attack is not None else {}
        if attack is None:
            time.sleep(seconds)
        polls1, t1 = indicator_polls(url), time.monotonic()
    return {
        "duration_s": round(t1 - t0, 2),
        "poll_rate_hz": round((polls1 - polls0) / (t1 - t0), 2),
        "load_average_1min": round(os.getloadavg()[0], 2),
        **watch.summary(),
        **counts,
    }


def calibrate(api: httpx.Client) -> int:
    """Import the bundled dataset, identify (lm), accept; the robot id."""
    r = api.post("/campaigns", json={"name": "bench", "robot_model": DEFAULT_ROBOT_MODEL})
    r.raise_for_status()
    cid, rid = int(r.json()["id"]), int(r.json()["robot_id"])
    r = api.post(
        f"/campaigns/{cid}/samples/import",
        content=bundled_dataset_text(),
        headers={"Content-Type": "text/csv"},
    )
    r.raise_for_status()
    r = api.post(f"/campaigns/{cid}/identifications", json={"method": "lm"})
    r.raise_for_status()
    jid = r.json()["id"]

    def done() -> Any:
        job = api.get(f"/identifications/{jid}").json()
        return job if job["status"] in ("succeeded", "failed", "cancelled") else None

    job = wait_for(done, 600, 0.5, f"job {jid}")
    if job["status"] != "succeeded":
        raise RuntimeError(f"job {jid}: {job}")
    if not job["accepted"]:
        api.post(f"/identifications/{jid}/accept").raise_for_status()
    return rid


def run_tree(name: str, tree: Path, page: int, seconds: float) -> dict[str, Any]:
    here = Path.cwd()
    os.chdir(tree)  # `python -m daemon` imports from the working directory first
    try:
        with tempfile.TemporaryDirectory(prefix=f"cablecal-h5-{name}-") as tmp:
            env = {"PYTHONPATH": str(tree), "CABLECAL_SAMPLER__SETTLE_S": "0.3"}
            with Cell(Path(tmp), SIM, daemon_env=env) as cell:
                assert cell.daemon is not None
                url, token = cell.daemon.url, cell.daemon.token
                pid = cell.daemon.popen.pid
                api = cell.daemon.client(timeout_s=120)
                rid = calibrate(api)
                for k in range(CAMPAIGNS):
                    api.post(
                        "/campaigns",
                        json={"name": f"c{k}", "robot_model": DEFAULT_ROBOT_MODEL, "notes": NOTES},
                    ).raise_for_status()
                time.sleep(3.0)
                idle = phase(url, pid, seconds)
                host, port = url.removeprefix("http://").rsplit(":", 1)
                body = crafted_upload()

                def attack(deadline: float) -> dict[str, Any]:
                    up: Counter[str] = Counter()
                    slow: Counter[str] = Counter()
                    threads = [
                        threading.Thread(
                            target=uploader, args=(url, token, rid, body, deadline, up)
                        )
                        for _ in range(UPLOADERS)
                    ] + [
                        threading.Thread(
                            target=slow_reader,
                            args=((host, int(port)), token, page, deadline, slow),
                        )
                        for _ in range(SLOW_READERS)
                    ]
                    for t in threads:
                        t.start()
                    for t in threads:
                        t.join()
                    return {"upload_statuses": dict(up), "slow_readers": dict(slow)}

                attacked = phase(url, pid, seconds, attack)
                after = phase(url, pid, seconds / 2)
    finally:
        os.chdir(here)
    idle_hz = idle["poll_rate_hz"]
    return {
        "tree": name,
        "page": page,
        "idle": idle,
        "attack": attacked,
        "idle_after": after,
        "attack_over_idle": round(attacked["poll_rate_hz"] / idle_hz, 3) if idle_hz else None,
    }


def markdown(results: dict[str, Any]) -> str:
    lines = [
        "# Hardening, fifth round (issue 31): the sampler under attack, before and after",
        "",
        f"One run of `python -m bench.hardening5` on {results['date']}: the EMULATED cell and "
        f"`cablecal serve` as real processes on loopback, indicator at 9600 baud, "
        f"{os.cpu_count()} cores shared with other work (load per phase below). *before* is "
        f"revision `{results['before_rev']}` (unpacked with `git archive`), *after* this tree. "
        f"Phases of {results['phase_s']:.0f} s: idle, then the attack ({UPLOADERS} clients "
        "posting a crafted 300 KiB multipart upload to the filter route "
        + (
            f"each every {results['upload_period_s']:g} s (six at once, again and again)"
            if results["upload_period_s"]
            else "back to back (a flood)"
        )
        + ", 16,000 "
        f"RFC 2231 `filename*N` parameters in one part; {SLOW_READERS} slow readers asking for "
        f"the largest `GET /campaigns` page the tree allows of {CAMPAIGNS} campaigns with "
        "10,000-character notes, reading none of it), then idle again for half a phase. "
        "`/health` sampled at 20 Hz (a timeout counts 5 s); RSS the largest seen every 0.25 s.",
        "",
        "| tree | phase | poll rate [Hz] | of idle | /health p50 / p99 / max [ms] | RSS daemon / "
        "with children [MiB] | load | attack requests |",
        "|---|---|---:|---:|---|---|---:|---|",
    ]
    for r in results["trees"]:
        idle_hz = r["idle"]["poll_rate_hz"]
        for ph in ("idle", "attack", "idle_after"):
            p = r[ph]
            share = f"{100 * p['poll_rate_hz'] / idle_hz:.0f} %" if idle_hz else "-"
            extra = ""
            if ph == "attack":
                extra = f"uploads {p['upload_statuses']}; slow readers {p['slow_readers']}"
            lines.append(
                f"| {r['tree']} | {ph.replace('_', ' ')} | {p['poll_rate_hz']:.2f} | {share} | "
                f"{p['health_p50_ms']} / {p['health_p99_ms']} / {p['health_max_ms']} | "
                f"{p['rss_daemon_mib']} / {p['rss_with_children_mib']} | "
                f"{p['load_average_1min']} | {extra} |"
            )
    lines += [
        "",
        f"Slow readers ask for `limit={results['trees'][0]['page']}` before (its cap) and "
        f"`limit={results['trees'][-1]['page']}` after (the cap of large-row pages); after, a "
        "reader that reads nothing for `[requests] send_timeout_s` (30 s) is cut, so within "
        "one phase they stay connected in both.",
        "",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--before", default=BEFORE_REV, help="git revision of the 'before'")
    parser.add_argument("--phase-s", type=float, default=PHASE_S, help="seconds per phase")
    parser.add_argument("--flood", action="store_true", help="uploads back to back")
    parser.add_argument("--out", default="hardening5", help="name of the .json/.md written")
    args = parser.parse_args(argv)
    global UPLOAD_PERIOD_S
    if args.flood:
        UPLOAD_PERIOD_S = 0.0
    trees = []
    with tempfile.TemporaryDirectory(prefix="cablecal-h5-tree-") as tmp:
        archive = subprocess.run(
            ["git", "-C", str(ROOT), "archive", args.before], check=True, capture_output=True
        ).stdout
        subprocess.run(["tar", "-x", "-C", tmp], input=archive, check=True)
        trees.append(run_tree("before", Path(tmp), 10_000, args.phase_s))
        trees.append(run_tree("after", ROOT, 500, args.phase_s))
    results = {
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "before_rev": args.before,
        "phase_s": args.phase_s,
        "upload_period_s": UPLOAD_PERIOD_S,
        "trees": trees,
    }
    (OUT / f"{args.out}.json").write_text(json.dumps(results, indent=2) + "\n")
    (OUT / f"{args.out}.md").write_text(markdown(results))
    print(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()
