"""The operator page's performance on the EMULATED cell (real processes, headless chromium).

Starts the emulated cell and ``cablecal serve`` (auto capture on, so the sampler polls and
stores), opens the page in Debian's chromium through Playwright, and measures:

- first paint: ``first-contentful-paint`` of the page load on localhost (target < 1 s), and
  the time until the live trace has drawn its first data;
- live trace rate: chart updates per second over the whole run (target >= 5 Hz), read from
  the page's own counter (``window.__cablecal.trace.updates``);
- memory: the tab's JS heap (CDP ``Performance.getMetrics`` ``JSHeapUsedSize``, after a
  forced garbage collection) at the start and at the end of a ``RUN_S`` (2 min) run with the
  page open; target: no growth (end within 10 % + 1 MB of the start);
- ``GET /api/v1/status`` latency (open-loop 200 req/s for 20 s, bench.api_bench's load
  generator) with the page open, and, in the same run, without it as the baseline (target:
  p99 < 20 ms with the page open).

Run: ``python -m bench.web_bench`` (``make bench`` calls it). Writes bench/web_results.json
and bench/web_results.md. Needs /usr/bin/chromium and the playwright package (test extras).
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from bench.api_bench import SIM, _load, errors_text
from calib.default_robot import DEFAULT_ROBOT_MODEL
from daemon.cli.emulated import FAST_DAEMON_ENV, Cell

OUT = Path(__file__).resolve().parent
ROOT = OUT.parent
RUN_S = 120.0
LOAD_RATE_HZ = 200.0
LOAD_S = 20.0
VIEWPORT = (1366, 768)


def _heap_mb(cdp: Any) -> float:
    """JS heap in use [MB] after a forced garbage collection."""
    cdp.send("HeapProfiler.collectGarbage")
    metrics = {m["name"]: m["value"] for m in cdp.send("Performance.getMetrics")["metrics"]}
    return float(metrics["JSHeapUsedSize"]) / 2**20


def _measure(url: str, token: str, run_s: float) -> dict[str, Any]:
    sys.path.insert(0, str(ROOT / "tests"))
    from browser import offline_page  # tests/browser.py: chromium, other hosts blocked

    out: dict[str, Any] = {}
    with offline_page(VIEWPORT, allowed_origin=url) as (page, log):
        t0 = time.perf_counter()
        page.goto(f"{url}/#token={token}")
        page.wait_for_function("window.__cablecal && window.__cablecal.trace.updates > 0")
        out["first_trace_s"] = round(time.perf_counter() - t0, 3)
        paint = page.evaluate(
            "performance.getEntriesByName('first-contentful-paint').map(e => e.startTime)"
        )
        out["first_contentful_paint_ms"] = round(float(paint[0]), 1) if paint else None
        cdp = page.context.new_cdp_session(page)
        cdp.send("Performance.enable")
        page.wait_for_timeout(5000)  # warm-up: charts built, first polls done
        heap_start = _heap_mb(cdp)
        n0 = page.evaluate("window.__cablecal.trace.updates")
        t_start = time.perf_counter()
        out["status_with_page"] = _load(url + "/api/v1/status", token, LOAD_RATE_HZ, LOAD_S)
        rest = run_s - (time.perf_counter() - t_start)
        if rest > 0:
            page.wait_for_timeout(rest * 1000)
        n1 = page.evaluate("window.__cablecal.trace.updates")
        elapsed = time.perf_counter() - t_start
        heap_end = _heap_mb(cdp)
        out.update(
            run_s=round(elapsed, 1),
            trace_updates_hz=round((n1 - n0) / elapsed, 2),
            js_heap_start_mb=round(heap_start, 2),
            js_heap_end_mb=round(heap_end, 2),
            console_errors=log.console_errors,
            page_errors=log.page_errors,
            blocked_requests=log.blocked_requests,
        )
    return out


def run(run_s: float = RUN_S) -> dict[str, Any]:
    """Measure and write bench/web_results.{json,md}; returns the results."""
    with tempfile.TemporaryDirectory(prefix="cablecal-webbench-") as tmp:
        env = {**FAST_DAEMON_ENV}
        with Cell(Path(tmp), SIM.format(baud=115200), daemon_env=env) as cell:
            assert cell.daemon is not None
            api = cell.daemon.client()
            cid = api.post("/campaigns", json={"name": "bench", "robot_model": DEFAULT_ROBOT_MODEL})
            api.put(f"/campaigns/{cid.json()['id']}/auto-capture", json={"enabled": True})
            time.sleep(3.0)
            baseline = _load(cell.daemon.url + "/api/v1/status", cell.token, LOAD_RATE_HZ, LOAD_S)
            page = _measure(cell.daemon.url, cell.token, run_s)
            poll_hz = api.get("/status").json()["devices"]["indicator"]["poll_rate_hz"]
    growth = page["js_heap_end_mb"] - page["js_heap_start_mb"]
    results = {
        "load_average_1min": round(os.getloadavg()[0], 2),
        "viewport": list(VIEWPORT),
        "indicator_poll_rate_hz": round(poll_hz, 1),
        **page,
        "js_heap_growth_mb": round(growth, 2),
        "status_without_page": baseline,
        "targets": {
            "first_contentful_paint_ms": 1000,
            "trace_updates_hz": 5.0,
            "js_heap_growth": "<= 10 % + 1 MB",
            "status_p99_ms": 20.0,
        },
    }
    fcp = page["first_contentful_paint_ms"]
    results["met"] = {
        "first_paint": fcp is not None and fcp < 1000,
        "trace_rate": page["trace_updates_hz"] >= 5.0,
        "memory": growth <= 0.1 * page["js_heap_start_mb"] + 1.0,
        "status_p99": page["status_with_page"]["p99_ms"] < 20.0,
        "no_console_errors": not page["console_errors"] and not page["page_errors"],
        "no_other_host": not page["blocked_requests"],
    }
    (OUT / "web_results.json").write_text(json.dumps(results, indent=2) + "\n")
    (OUT / "web_results.md").write_text(_markdown(results))
    return results


def _markdown(r: dict[str, Any]) -> str:
    def ok(key: str) -> str:
        return "met" if r["met"][key] else "NOT met"

    w, wo = r["status_with_page"], r["status_without_page"]
    return "\n".join(
        [
            f"# Operator page performance (EMULATED cell, headless chromium {r['viewport'][0]}x"
            f"{r['viewport'][1]}, {r['run_s']:.0f} s with the page open)",
            "",
            "| measure | value | target | |",
            "|---|---|---|---|",
            f"| first contentful paint | {r['first_contentful_paint_ms']} ms | < 1000 ms | "
            f"{ok('first_paint')} |",
            f"| page load to first trace data | {r['first_trace_s'] * 1000:.0f} ms | | |",
            f"| live trace chart updates | {r['trace_updates_hz']} per s | >= 5 | "
            f"{ok('trace_rate')} |",
            f"| JS heap start → end (after GC) | {r['js_heap_start_mb']} → "
            f"{r['js_heap_end_mb']} MB ({r['js_heap_growth_mb']:+.2f}) | no growth | "
            f"{ok('memory')} |",
            f"| GET /status p99, page open | {w['p99_ms']} ms (p50 {w['p50_ms']}) | < 20 ms | "
            f"{ok('status_p99')} |",
            f"| GET /status p99, no page (baseline, same run) | {wo['p99_ms']} ms (p50 "
            f"{wo['p50_ms']}) | | |",
            f"| GET /status errors (kinds), page open / no page | {errors_text(w)} / "
            f"{errors_text(wo)} of {w['requests']} / {wo['requests']} | | |",
            f"| console errors / requests to other hosts | {len(r['console_errors'])} / "
            f"{len(r['blocked_requests'])} | 0 / 0 | "
            f"{ok('no_console_errors')} / {ok('no_other_host')} |",
            "",
            f"/status load: open-loop {LOAD_RATE_HZ:.0f} req/s for {LOAD_S:.0f} s "
            f"(bench.api_bench's generator). Indicator polled at "
            f"{r['indicator_poll_rate_hz']} Hz (115200 baud), auto "
            f"capture on. Load average (1 min) at the end: {r['load_average_1min']} on "
            f"{os.cpu_count()} shared cores. Run: `python -m bench.web_bench` (`make bench`).",
            "",
        ]
    )


if __name__ == "__main__":
    print(json.dumps(run(), indent=2))
