"""The indicator's poll rate while the service filters one 16 MiB RAPID upload (issue 34 item 8).

The EMULATED cell and ``cablecal serve`` of this tree as real processes on loopback
(indicator at 9600 baud, the set-up of :mod:`bench.hardening5`, whose helpers this reuses):
the bundled dataset is identified and accepted, then two phases are measured:

- **idle**: nothing but the measurement, ``IDLE_S`` seconds;
- **filter**: one ``POST /robots/{id}/filter`` of the bench's 16 MiB module
  (:data:`bench.filter_bench.UPLOAD_TARGETS` targets in real shapes,
  :func:`bench.filter_shapes.rapid_shapes`, on the cell's arm), from the first byte sent to
  the response.

Per phase: the indicator poll rate (``cablecal_device_polls_total`` over wall time),
``GET /health`` latency at 20 Hz, the largest RSS of the daemon and of the daemon with its
children (the filter's worker process), the load average; for the filter its status and
time. Run: ``python -m bench.filter_polling`` (about 3 minutes on a quiet machine). Writes
bench/filter_polling.json and bench/filter_polling.md.
"""

from __future__ import annotations

import json
import os
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import httpx
import numpy as np

from bench.filter_bench import UPLOAD_TARGETS
from bench.filter_shapes import rapid_shapes
from bench.hardening5 import SIM, calibrate, phase
from calib.default_robot import DEFAULT_ROBOT_MODEL
from calib.models import builtin_model
from daemon.cli.emulated import Cell

OUT = Path(__file__).resolve().parent
ROOT = OUT.parent
IDLE_S = 20.0
#: The longest the filter request may take [s].
FILTER_TIMEOUT_S = 900.0
BOUNDARY = "b0undary"


def upload_body() -> tuple[bytes, int]:
    """The multipart body of one RAPID module just under 16 MiB (the service's limit) for the
    cell's arm; its module's size [bytes]."""
    import sys

    sys.path.insert(0, str(ROOT / "tests"))
    from filter_cells import rapid_confdata, regular_poses, tool_frame, work_frame

    nominal = replace(builtin_model(DEFAULT_ROBOT_MODEL), tool_mm=np.zeros(3))
    q = regular_poses(nominal, UPLOAD_TARGETS, seed=3)
    tools = [tool_frame(185.0), tool_frame(220.0, 10.0), tool_frame(240.0, 30.0)]
    text = rapid_shapes(nominal, q, tools, work_frame(), rapid_confdata(nominal, q)).encode()
    head = (
        f'--{BOUNDARY}\r\nContent-Disposition: form-data; name="files"; '
        'filename="UPLOAD.mod"\r\nContent-Type: application/octet-stream\r\n\r\n'
    ).encode()
    return head + text + f"\r\n--{BOUNDARY}--\r\n".encode(), len(text)


def run(idle_s: float) -> dict[str, Any]:
    body, module_bytes = upload_body()
    here = Path.cwd()
    os.chdir(ROOT)  # `python -m daemon` imports from the working directory first
    try:
        with tempfile.TemporaryDirectory(prefix="cablecal-filter-polling-") as tmp:
            env = {"PYTHONPATH": str(ROOT), "CABLECAL_SAMPLER__SETTLE_S": "0.3"}
            with Cell(Path(tmp), SIM, daemon_env=env) as cell:
                assert cell.daemon is not None
                url, token = cell.daemon.url, cell.daemon.token
                pid = cell.daemon.popen.pid
                rid = calibrate(cell.daemon.client(timeout_s=120))
                time.sleep(3.0)
                idle = phase(url, pid, idle_s)

                def post(deadline: float) -> dict[str, Any]:
                    del deadline  # the phase lasts as long as the request
                    t0 = time.monotonic()
                    headers = {
                        "Authorization": f"Bearer {token}",
                        "Content-Type": f"multipart/form-data; boundary={BOUNDARY}",
                    }
                    with httpx.Client(timeout=FILTER_TIMEOUT_S) as c:
                        r = c.post(
                            f"{url}/api/v1/robots/{rid}/filter?dry_run=true",
                            content=body,
                            headers=headers,
                        )
                    out: dict[str, Any] = {
                        "status": r.status_code,
                        "request_s": round(time.monotonic() - t0, 2),
                    }
                    if r.status_code == 200:
                        counts = r.json().get("counts", {})
                        out["targets"] = counts.get("targets")
                        out["corrected"] = counts.get("corrected")
                    else:
                        out["detail"] = r.text[:300]
                    return out

                filtering = phase(url, pid, 0.0, post)
    finally:
        os.chdir(here)
    idle_hz = idle["poll_rate_hz"]
    return {
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "module_bytes": module_bytes,
        "body_bytes": len(body),
        "idle": idle,
        "filter": filtering,
        "filter_over_idle": round(filtering["poll_rate_hz"] / idle_hz, 3) if idle_hz else None,
    }


def markdown(r: dict[str, Any]) -> str:
    lines = [
        "# The indicator while the service filters a 16 MiB upload",
        "",
        f"One run of `python -m bench.filter_polling` on {r['date']}: the EMULATED cell and "
        "`cablecal serve` of this tree as real processes on loopback, indicator at 9600 baud, "
        f"{os.cpu_count()} cores SHARED with other work (other sessions ran their tests and "
        "benches at the same time: the load average is in the table). The upload: one RAPID "
        f"module of {r['module_bytes']:,} bytes ({UPLOAD_TARGETS:,} targets in real shapes, "
        "`bench/filter_shapes.py`), `POST /robots/{id}/filter?dry_run=true`; the filter runs "
        "in the service's worker process.",
        "",
        "| phase | s | poll rate [Hz] | /health p50 [ms] | p99 [ms] | max [ms] | daemon RSS "
        "[MiB] | with children [MiB] | load (1 min) | request |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---|",
    ]
    for name in ("idle", "filter"):
        p = r[name]
        req = ""
        if name == "filter":
            req = f"{p['status']} in {p['request_s']} s"
            if p.get("targets") is not None:
                req += f", {p['corrected']:,} of {p['targets']:,} corrected"
        lines.append(
            f"| {name} | {p['duration_s']} | {p['poll_rate_hz']} | {p['health_p50_ms']} | "
            f"{p['health_p99_ms']} | {p['health_max_ms']} | {p['rss_daemon_mib']} | "
            f"{p['rss_with_children_mib']} | {p['load_average_1min']} | {req} |"
        )
    lines += [
        "",
        f"Poll rate while filtering over idle: **{r['filter_over_idle']}** (the issue's bar: "
        "≥ 0.95).",
        "",
    ]
    return "\n".join(lines)


def main() -> None:
    results = run(IDLE_S)
    (OUT / "filter_polling.json").write_text(json.dumps(results, indent=2) + "\n")
    (OUT / "filter_polling.md").write_text(markdown(results))
    print(markdown(results))


if __name__ == "__main__":
    main()
