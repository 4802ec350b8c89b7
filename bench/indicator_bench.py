"""Indicator poll rate over a pseudo-terminal against the emulated HY9648, next to the link
limit computed from frame sizes.

The emulated indicator runs in its own process (``python -m simulator``) and paces its bytes
at the baud rate; the driver polls the default block (value, decimals, status: 8 registers)
as fast as it can.

Link limit per poll: ``(request + reply characters) · t_char + 2 · t3.5`` (the Modbus
silent interval after each frame; 1.75 ms above 19200 baud), with ``t_char = 10 bits / baud``
for 8N1. Target: the driver reaches ≥ 90 % of it.

Run: ``python -m bench.indicator_bench`` (prints JSON).
"""

from __future__ import annotations

import asyncio
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from drivers.indicator import IndicatorConfig, ModbusIndicator

BAUDS = (9600, 115200)
DURATION_S = 3.0


def link_limit_hz(
    baud: int, request_bytes: int, reply_bytes: int, bits_per_char: int = 10
) -> float:
    """Polls per second the line allows for one request/reply pair."""
    char_s = bits_per_char / baud
    t35 = 0.00175 if baud > 19200 else 3.5 * char_s
    return 1.0 / ((request_bytes + reply_bytes) * char_s + 2 * t35)


async def _poll(port: str, baud: int, duration_s: float) -> tuple[int, float, int]:
    ind = ModbusIndicator(IndicatorConfig(port=port, baud=baud, timeout_s=0.5))
    errors = 0
    try:
        await ind.read()  # open the port, warm up
        n, t0 = 0, time.monotonic()
        while time.monotonic() - t0 < duration_s:
            try:
                await ind.read()
                n += 1
            except Exception:
                errors += 1
        return n, time.monotonic() - t0, errors
    finally:
        await ind.close()


def bench_baud(baud: int, duration_s: float = DURATION_S) -> dict[str, Any]:
    """Poll rate at ``baud`` against an emulated indicator in a child process."""
    with tempfile.TemporaryDirectory() as tmp:
        cfg = Path(tmp) / "sim.toml"
        cfg.write_text(
            f"[indicator]\nbaud = {baud}\nnoise_mm = 0.02\n"
            "[robot_socketcmd]\nenabled = false\n[robot_modbus]\nenabled = false\n"
            "[control]\nenabled = false\n"
        )
        proc = subprocess.Popen(
            [sys.executable, "-m", "simulator", "--config", str(cfg)],
            stdout=subprocess.PIPE,
            text=True,
            cwd=Path(__file__).resolve().parents[1],
        )
        try:
            assert proc.stdout is not None
            line = proc.stdout.readline()
            if not line.startswith("READY "):
                raise RuntimeError(f"emulated cell did not start: {line!r}")
            port = json.loads(line[6:])["indicator_port"]
            n, elapsed, errors = asyncio.run(_poll(port, baud, duration_s))
        finally:
            proc.terminate()
            proc.wait(timeout=10)
    count = 8  # registers in the default block read
    request, reply = 8, 5 + 2 * count
    limit = link_limit_hz(baud, request, reply)
    rate = n / elapsed
    return {
        "baud": baud,
        "request_bytes": request,
        "reply_bytes": reply,
        "polls": n,
        "errors": errors,
        "poll_rate_hz": round(rate, 2),
        "link_limit_hz": round(limit, 2),
        "fraction_of_limit": round(rate / limit, 3),
        "target_met": rate >= 0.9 * limit,
    }


def run() -> dict[str, Any]:
    """Indicator poll rate over a pty at 9600 and 115200 baud vs the link limit."""
    results = [bench_baud(b) for b in BAUDS]
    return {
        "name": "indicator_poll_rate_pty",
        "note": "emulated HY9648 (paced at the baud rate) in a child process; 8-register reads",
        "target_fraction": 0.9,
        "results": results,
    }


if __name__ == "__main__":
    print(json.dumps(run(), indent=2))
