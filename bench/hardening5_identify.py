"""The sampler while identifications are submitted on a 350k-row campaign, before and after
(issue 31 item 4), in one run on loopback.

For each tree (as :mod:`bench.hardening5`: ``before`` unpacked from a git revision, ``after``
this tree) it starts the EMULATED cell and ``cablecal serve``, imports the bundled dataset
(2017 samples) repeated to :data:`ROWS` rows in two imports (each under the 20 MiB import
limit), then measures an idle phase and a phase in which one client, back to back, submits an
identification (``POST /campaigns/{id}/identifications``, method ``lm``), cancels it at once
(``DELETE``: the bench measures the submission, not the solver) and asks the readiness
route. Same measures as :mod:`bench.hardening5` (indicator poll rate, ``/health`` at 20 Hz,
RSS).

Run: ``python -m bench.hardening5_identify [--before REV] [--phase-s S]`` (about 5 minutes).
Writes bench/hardening5_identify.json and bench/hardening5_identify.md.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from collections import Counter
from pathlib import Path
from typing import Any

import httpx

from bench.cellrun import ROOT, daemon_of, phase, unpacked
from bench.hardening5 import BEFORE_REV, OUT
from calib.default_robot import DEFAULT_ROBOT_MODEL
from daemon.datafiles import bundled_dataset_text

ROWS = 350_000
IMPORTS = 2
PHASE_S = 20.0


def import_bodies() -> list[str]:
    """:data:`IMPORTS` CSV texts that hold :data:`ROWS` rows together (the bundled dataset's
    rows repeated)."""
    header, *rows = bundled_dataset_text().strip().splitlines()
    per = ROWS // IMPORTS
    out = []
    for _ in range(IMPORTS):
        body = [rows[k % len(rows)] for k in range(per)]
        out.append("\n".join([header, *body]) + "\n")
    return out


def submitter(api: httpx.Client, cid: int) -> Any:
    def run(deadline: float) -> dict[str, Any]:
        posts: Counter[str] = Counter()
        post_s: list[float] = []
        while time.monotonic() < deadline:
            t0 = time.monotonic()
            r = api.post(f"/campaigns/{cid}/identifications", json={"method": "lm"})
            post_s.append(time.monotonic() - t0)
            posts[f"POST {r.status_code}"] += 1
            if r.status_code == 202:
                job_id = r.json()["id"]
                posts[f"DELETE {api.delete(f'/identifications/{job_id}').status_code}"] += 1
            r = api.get(f"/campaigns/{cid}/identification-readiness")
            posts[f"readiness {r.status_code}"] += 1
        return {
            "requests": dict(posts),
            "post_median_s": round(sorted(post_s)[len(post_s) // 2], 2) if post_s else None,
        }

    return run


def run_tree(name: str, tree: Path, seconds: float) -> dict[str, Any]:
    with daemon_of(tree) as daemon:
        url, pid = daemon.url, daemon.popen.pid
        api = daemon.client(timeout_s=300)
        r = api.post("/campaigns", json={"name": "big", "robot_model": DEFAULT_ROBOT_MODEL})
        r.raise_for_status()
        cid = int(r.json()["id"])
        for body in import_bodies():
            api.post(
                f"/campaigns/{cid}/samples/import",
                content=body,
                headers={"Content-Type": "text/csv"},
            ).raise_for_status()
        n = api.get(f"/campaigns/{cid}").json()["n_included"]
        time.sleep(3.0)
        idle = phase(url, pid, seconds)
        busy = phase(url, pid, seconds, submitter(api, cid))
    return {"tree": name, "rows": n, "idle": idle, "submitting": busy}


def markdown(results: dict[str, Any]) -> str:
    lines = [
        "# Hardening, fifth round (issue 31 item 4): submissions on a 350k-row campaign",
        "",
        f"One run of `python -m bench.hardening5_identify` on {results['date']}: the EMULATED "
        "cell and `cablecal serve` as real processes on loopback, indicator at 9600 baud, "
        f"{os.cpu_count()} cores shared with other work. *before* is revision "
        f"`{results['before_rev']}`, *after* this tree. A campaign of {ROWS:,} rows (the "
        f"bundled dataset repeated, {IMPORTS} imports); phases of {results['phase_s']:.0f} s: "
        "idle, then one client submitting an identification, cancelling it at once and asking "
        "the readiness route, back to back. `/health` sampled at 20 Hz (a timeout counts 5 s).",
        "",
        "| tree | phase | poll rate [Hz] | of idle | /health p50 / p99 / max [ms] | RSS daemon / "
        "with children [MiB] | load | requests | POST median [s] |",
        "|---|---|---:|---:|---|---|---:|---|---:|",
    ]
    for r in results["trees"]:
        idle_hz = r["idle"]["poll_rate_hz"]
        for ph in ("idle", "submitting"):
            p = r[ph]
            share = f"{100 * p['poll_rate_hz'] / idle_hz:.0f} %" if idle_hz else "-"
            lines.append(
                f"| {r['tree']} | {ph} | {p['poll_rate_hz']:.2f} | {share} | "
                f"{p['health_p50_ms']} / {p['health_p99_ms']} / {p['health_max_ms']} | "
                f"{p['rss_daemon_mib']} / {p['rss_with_children_mib']} | "
                f"{p['load_average_1min']} | {p.get('requests', '')} | "
                f"{p.get('post_median_s', '')} |"
            )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--before", default=BEFORE_REV, help="git revision of the 'before'")
    parser.add_argument("--phase-s", type=float, default=PHASE_S, help="seconds per phase")
    args = parser.parse_args(argv)
    with unpacked(args.before) as before:
        trees = [run_tree("before", before, args.phase_s)]
    trees.append(run_tree("after", ROOT, args.phase_s))
    results = {
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "before_rev": args.before,
        "phase_s": args.phase_s,
        "rows": ROWS,
        "trees": trees,
    }
    (OUT / "hardening5_identify.json").write_text(json.dumps(results, indent=2) + "\n")
    (OUT / "hardening5_identify.md").write_text(markdown(results))
    print(json.dumps(results, indent=2))


if __name__ == "__main__":
    main()
