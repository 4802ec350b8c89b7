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
import threading
import time
from collections import Counter
from pathlib import Path
from typing import Any

import httpx

from bench.cellrun import ROOT, daemon_of, phase, unpacked
from calib.default_robot import DEFAULT_ROBOT_MODEL
from daemon.cli.emulated import wait_for
from daemon.datafiles import bundled_dataset_text

OUT = Path(__file__).resolve().parent
#: The revision before issue 31's items 2-8 (the base of this work).
BEFORE_REV = "fad0e1d"
PHASE_S = 20.0
CAMPAIGNS = 600
NOTES = '"' * 10_000  # 20 kB each as JSON
UPLOADERS = 6
#: Seconds between the starts of one client's uploads (0: back to back); ``--flood`` sets 0.
UPLOAD_PERIOD_S = 1.0
SLOW_READERS = 5
BOUNDARY = "b0undary"


def crafted_upload() -> bytes:
    """A 300 KiB multipart body: one part whose Content-Disposition carries 16,000 RFC 2231
    ``filename*N`` continuations (quadratic in the standard library's email parser)."""
    params = "".join(f"; filename*{k}=x" for k in range(16_000))
    head = f'--{BOUNDARY}\r\nContent-Disposition: form-data; name="files"{params}\r\n\r\n'
    return (head + "MODULE M\nENDMODULE\n\r\n" + f"--{BOUNDARY}--\r\n").encode()


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


def run_tree(
    name: str, tree: Path, page: int, seconds: float, env: dict[str, str] | None = None
) -> dict[str, Any]:
    with daemon_of(tree, env) as daemon:
        url, token, pid = daemon.url, daemon.token, daemon.popen.pid
        api = daemon.client(timeout_s=120)
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
                threading.Thread(target=uploader, args=(url, token, rid, body, deadline, up))
                for _ in range(UPLOADERS)
            ] + [
                threading.Thread(
                    target=slow_reader, args=((host, int(port)), token, page, deadline, slow)
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
    with unpacked(args.before) as before:
        trees = [run_tree("before", before, 10_000, args.phase_s)]
    # The setup's 600 campaigns are over [requests] campaigns_per_min (a tree before it has
    # no such setting, and refuses an unknown one).
    unlimited = {"CABLECAL_REQUESTS__CAMPAIGNS_PER_MIN": "0"}
    trees.append(run_tree("after", ROOT, 500, args.phase_s, unlimited))
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
