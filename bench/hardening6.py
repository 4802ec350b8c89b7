"""Issue 31, sixth pass: a flood of uploads against the per-peer rate, a 350k-row CSV export,
and four 16 MiB filter uploads at once; before and after in one run (loopback only).

For each tree (``before``: a git revision unpacked with ``git archive``; ``after``: this
working tree) it starts the EMULATED cell and ``cablecal serve`` from that tree
(:mod:`bench.cellrun`), identifies and accepts the bundled dataset (the filter route needs a
calibration), imports :data:`EXPORT_ROWS` rows into a second campaign, then measures:

- **idle** for ``PHASE_S``;
- **flood**: :data:`UPLOADERS` clients from another loopback address (127.0.0.2, a peer of
  its own) posting the crafted 300 KiB multipart upload of :mod:`bench.hardening5` to the
  filter route back to back, ignoring Retry-After, for ``PHASE_S``;
- **idle after** for half a phase;
- **export**: one ``GET /campaigns/{id}/samples?format=csv`` of the 350k-row campaign read
  at once to its end: its time, and the daemon's RSS (the largest seen every 0.25 s);
- **4 x 16 MiB filters** (``--filters``, this tree only: the filter path is the same in
  both): four clients from 127.0.0.2 each uploading a 16 MiB RAPID module at once; each
  answer's status, whether the route's OpenAPI lists it, and its time.

Measured per phase as :mod:`bench.hardening5`: the indicator poll rate, ``GET /health`` at
20 Hz (p50, p99, max), the RSS of the daemon and of the daemon with its children.

Run: ``python -m bench.hardening6 [--before REV] [--phase-s S] [--no-filters]`` (about 10
minutes). Writes bench/hardening6.json and bench/hardening6.md.
"""

from __future__ import annotations

import argparse
import json
import os
import threading
import time
from collections import Counter
from pathlib import Path
from typing import Any

import httpx
import numpy as np
from calib.filter.rotations import matrix_to_quat_wxyz

from bench.cellrun import ROOT, daemon_of, phase, unpacked
from bench.hardening5 import BOUNDARY, calibrate, crafted_upload
from bench.hardening5_identify import import_bodies
from calib.default_robot import DEFAULT_ROBOT_MODEL
from calib.filter.kin import flange_frames
from calib.models import builtin_model

OUT = Path(__file__).resolve().parent
#: The branch's base: the tree before the per-peer rate and the streamed export.
BEFORE_REV = "d6f5408"
PHASE_S = 20.0
UPLOADERS = 6
#: The attackers' source address: a peer other than the measuring client's 127.0.0.1.
ATTACKER = "127.0.0.2"
FILTERS = 4
#: A filter client's timeout [s]: the answer must come within it.
FILTER_TIMEOUT_S = 600.0
#: Largest filter body of the route [bytes] (daemon.api.http.guard.MAX_FILTER_BYTES), less room
#: for the multipart framing.
FILTER_FILE_BYTES = 16 * 1024 * 1024 - 2048


def rapid_module(size_bytes: int, seed: int = 0) -> bytes:
    """A RAPID module of about ``size_bytes``: reachable robtargets of the default robot
    (flange poses of random joints inside its limits, confdata 0) and a ``MoveL`` to each,
    400 per routine."""
    nominal = builtin_model(DEFAULT_ROBOT_MODEL)
    n = size_bytes // 182  # about 178 bytes a target
    rng = np.random.default_rng(seed)
    lo = np.array([-120.0, -60.0, 100.0, -90.0, -60.0, -90.0])
    q = lo + rng.random((n, 6)) * (np.array([120.0, 30.0, 200.0, 90.0, 60.0, 90.0]) - lo)
    frames = flange_frames(nominal, q)  # (n, 4, 4) [mm]
    ext = "[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]"
    decl, procs = ["MODULE BIG"], []
    for k in range(n):
        p = ",".join(f"{v:.3f}" for v in frames[k, :3, 3])
        r = ",".join(f"{v:.6f}" for v in matrix_to_quat_wxyz(frames[k, :3, :3]))
        decl.append(f"  CONST robtarget p{k}:=[[{p}],[{r}],[0,0,0,0],{ext}];")
        if k % 400 == 0:
            procs += ([] if k == 0 else ["  ENDPROC"]) + [f"  PROC r{k // 400}()"]
        procs.append(f"    MoveL p{k},v100,fine,tool0;")
    text = "\n".join([*decl, *procs, "  ENDPROC", "ENDMODULE", ""])
    if len(text) > size_bytes:
        raise ValueError(f"the module is {len(text)} bytes, over {size_bytes}")
    return text.encode()


def multipart(name: str, data: bytes) -> bytes:
    head = (
        f'--{BOUNDARY}\r\nContent-Disposition: form-data; name="files"; filename="{name}"\r\n'
        "Content-Type: text/plain\r\n\r\n"
    ).encode()
    return head + data + f"\r\n--{BOUNDARY}--\r\n".encode()


def _client(timeout_s: float) -> httpx.Client:
    return httpx.Client(timeout=timeout_s, transport=httpx.HTTPTransport(local_address=ATTACKER))


def flood(url: str, token: str, rid: int) -> Any:
    body = crafted_upload()
    headers = {
        "Authorization": f"Bearer {token}",
        "Content-Type": f"multipart/form-data; boundary={BOUNDARY}",
    }

    def one(deadline: float, out: Counter[str]) -> None:
        with _client(30) as c:
            while time.monotonic() < deadline:
                try:
                    r = c.post(f"{url}/api/v1/robots/{rid}/filter", content=body, headers=headers)
                    out[str(r.status_code)] += 1
                except httpx.HTTPError as exc:
                    out[type(exc).__name__] += 1

    def attack(deadline: float) -> dict[str, Any]:
        counts: Counter[str] = Counter()
        threads = [threading.Thread(target=one, args=(deadline, counts)) for _ in range(UPLOADERS)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        return {"upload_statuses": dict(sorted(counts.items()))}

    return attack


def filters_at_once(url: str, token: str, rid: int, documented: set[str]) -> Any:
    body = multipart("big.mod", rapid_module(FILTER_FILE_BYTES - 200))
    headers = {
        "Authorization": f"Bearer {token}",
        "Content-Type": f"multipart/form-data; boundary={BOUNDARY}",
    }
    answers: list[dict[str, Any]] = []

    def one() -> None:
        t0 = time.monotonic()
        with _client(FILTER_TIMEOUT_S) as c:
            try:
                r = c.post(f"{url}/api/v1/robots/{rid}/filter", content=body, headers=headers)
                status = str(r.status_code)
                detail = r.text[:160] if r.status_code >= 400 else ""
            except httpx.HTTPError as exc:
                status, detail = type(exc).__name__, str(exc)[:160]
        answers.append(
            {
                "status": status,
                "documented": status in documented,
                "time_s": round(time.monotonic() - t0, 1),
                "detail": detail,
            }
        )

    def attack(deadline: float) -> dict[str, Any]:
        threads = [threading.Thread(target=one) for _ in range(FILTERS)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        return {"upload_bytes": len(body), "answers": answers}

    return attack


def export_once(api: httpx.Client, cid: int) -> Any:
    def attack(deadline: float) -> dict[str, Any]:
        t0 = time.monotonic()
        size = 0
        with api.stream("GET", f"/campaigns/{cid}/samples", params={"format": "csv"}) as r:
            first_s = time.monotonic() - t0
            for chunk in r.iter_bytes():
                size += len(chunk)
        return {
            "export_status": r.status_code,
            "export_mb": round(size / 1e6, 1),
            "export_first_byte_s": round(first_s, 2),
            "export_s": round(time.monotonic() - t0, 2),
        }

    return attack


def run_tree(name: str, tree: Path, seconds: float, filters: bool) -> dict[str, Any]:
    with daemon_of(tree) as daemon:
        url, token, pid = daemon.url, daemon.token, daemon.popen.pid
        api = daemon.client(timeout_s=600)
        rid = calibrate(api)
        r = api.post("/campaigns", json={"name": "big", "robot_model": DEFAULT_ROBOT_MODEL})
        r.raise_for_status()
        cid = int(r.json()["id"])
        for body in import_bodies():
            while True:  # a 10 MiB body counts the whole burst of the peer's rate: wait
                r = api.post(
                    f"/campaigns/{cid}/samples/import",
                    content=body,
                    headers={"Content-Type": "text/csv"},
                )
                if r.status_code != 429:
                    break
                time.sleep(float(r.headers.get("retry-after", "1")))
            r.raise_for_status()
        rows = api.get(f"/campaigns/{cid}").json()["n_included"]
        time.sleep(3.0)
        out: dict[str, Any] = {"tree": name, "export_rows": rows}
        out["idle"] = phase(url, pid, seconds)
        out["flood"] = phase(url, pid, seconds, flood(url, token, rid))
        out["idle_after"] = phase(url, pid, seconds / 2)
        out["export"] = phase(url, pid, 0.0, export_once(api, cid))
        if filters:
            spec = api.get(f"{url}/openapi.json").json()
            op = spec["paths"]["/api/v1/robots/{robot_id}/filter"]["post"]
            time.sleep(3.0)
            out["filters"] = phase(
                url, pid, 0.0, filters_at_once(url, token, rid, set(op["responses"]))
            )
    return out


def _row(tree: str, label: str, p: dict[str, Any], idle_hz: float, extra: str) -> str:
    share = f"{100 * p['poll_rate_hz'] / idle_hz:.0f} %" if idle_hz else "-"
    return (
        f"| {tree} | {label} | {p['poll_rate_hz']:.2f} | {share} | "
        f"{p['health_p50_ms']} / {p['health_p99_ms']} / {p['health_max_ms']} | "
        f"{p['rss_daemon_mib']} / {p['rss_with_children_mib']} | {p['load_average_1min']} | "
        f"{extra} |"
    )


def markdown(results: dict[str, Any]) -> str:
    lines = [
        "# Hardening, sixth pass (issue 31): flood, export, four 16 MiB filters",
        "",
        f"One run of `python -m bench.hardening6` on {results['date']}: the EMULATED cell and "
        "`cablecal serve` as real processes on loopback, indicator at 9600 baud, "
        f"{os.cpu_count()} cores shared with other work (load per phase below). *before* is "
        f"revision `{results['before_rev']}` (unpacked with `git archive`), *after* this tree. "
        f"Phases: idle {results['phase_s']:.0f} s; flood {results['phase_s']:.0f} s "
        f"({UPLOADERS} clients from {ATTACKER} posting the crafted 300 KiB upload of "
        "bench/hardening5.py back to back, ignoring Retry-After); idle again for half a "
        f"phase; one CSV export of {results['trees'][0]['export_rows']:,} rows read at once; "
        f"{FILTERS} 16 MiB RAPID uploads at once from {ATTACKER} (after only). `/health` "
        "sampled at 20 Hz from 127.0.0.1 (a timeout counts 5 s); RSS the largest seen every "
        "0.25 s.",
        "",
        "| tree | phase | poll rate [Hz] | of idle | /health p50 / p99 / max [ms] | RSS daemon / "
        "with children [MiB] | load | requests |",
        "|---|---|---:|---:|---|---|---:|---|",
    ]
    for r in results["trees"]:
        idle_hz = r["idle"]["poll_rate_hz"]
        lines.append(_row(r["tree"], "idle", r["idle"], idle_hz, ""))
        lines.append(
            _row(r["tree"], "flood", r["flood"], idle_hz, str(r["flood"]["upload_statuses"]))
        )
        lines.append(_row(r["tree"], "idle after", r["idle_after"], idle_hz, ""))
        e = r["export"]
        lines.append(
            _row(
                r["tree"],
                "export",
                e,
                idle_hz,
                f"{e['export_status']}, {e['export_mb']} MB, first byte {e['export_first_byte_s']} "
                f"s, all {e['export_s']} s",
            )
        )
        if "filters" in r:
            f = r["filters"]
            answers = "; ".join(
                f"{a['status']}{'' if a['documented'] else ' (not in OpenAPI)'} in {a['time_s']} s"
                for a in f["answers"]
            )
            lines.append(_row(r["tree"], f"{FILTERS} x 16 MiB filters", f, idle_hz, answers))
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--before", default=BEFORE_REV, help="git revision of the 'before'")
    parser.add_argument("--phase-s", type=float, default=PHASE_S, help="seconds per phase")
    parser.add_argument("--no-filters", action="store_true", help="skip the 16 MiB filters")
    args = parser.parse_args(argv)
    with unpacked(args.before) as before:
        trees = [run_tree("before", before, args.phase_s, False)]
    trees.append(run_tree("after", ROOT, args.phase_s, not args.no_filters))
    results = {
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "before_rev": args.before,
        "phase_s": args.phase_s,
        "trees": trees,
    }
    (OUT / "hardening6.json").write_text(json.dumps(results, indent=2) + "\n")
    (OUT / "hardening6.md").write_text(markdown(results))
    print(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()
