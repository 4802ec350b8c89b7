"""Robot joint reads per second and success rate over a lossy link (issue 11, defect 7;
issue 18 added the controller faces).

Each robot driver (Huashu SocketCmd, Modbus TCP with the UR preset, UR RTDE, ABB RWS 1.0)
reads joint angles back to back for ``DURATION_S`` from the emulated cell (in-process
:class:`SimulatorThread`, robot held still), with its default configuration, at 0 % and
10 % emulated reply drops (``robot_drop_rate``). Counted: good reads, failed reads (typed
driver errors), reconnects (successful connects after the first), and wrong reads (a value
differing from the cell's truth by more than the register resolution).

Run from a checkout: ``python -m bench.robot_link_bench`` (prints JSON; ``--out FILE`` also
writes a Markdown table, e.g. ``bench/robot_link.md``). To compare with
another revision, run the same file with that revision's root first on ``sys.path``
(``python bench/robot_link_bench.py --root /path/to/checkout``).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import sys
import time
from typing import Any

DURATION_S = 6.0
DROP_RATES = (0.0, 0.1)
#: Largest |reading - truth| [deg]: Huashu sends 6 decimals, UR registers are 1 mrad, RTDE
#: sends doubles, the emulated RWS 6 decimals.
TOLERANCE_DEG = {"huashu": 1e-5, "modbus": 0.03, "ur-rtde": 1e-9, "abb-rws": 1e-6}
#: Driver kind and READY key of each bench kind.
KINDS = {
    "huashu": ("huashu-socketcmd", "robot_socketcmd"),
    "modbus": ("modbus-tcp", "robot_modbus"),
    "ur-rtde": ("ur-rtde", "robot_ur_rtde"),
    "abb-rws": ("abb-rws", "robot_abb_rws"),
}


async def _run(kind: str, sim: Any, duration_s: float) -> dict[str, Any]:
    from drivers import DeviceError, make_robot  # the revision under test

    driver_kind, ready_key = KINDS[kind]
    endpoint = sim.ready[ready_key]
    host, port = endpoint.rsplit(":", 1)
    cfg = {"kind": driver_kind}
    robot: Any = make_robot({**cfg, "host": host, "port": int(port)})
    connects = 0
    backoff = robot._backoff
    succeeded = backoff.succeeded

    def counting() -> None:
        nonlocal connects
        connects += 1
        succeeded()

    backoff.succeeded = counting
    truth = sim.control("state")["joints_deg"]
    ok = failed = wrong = 0
    errors: dict[str, int] = {}
    longest_s = 0.0
    t_end = time.monotonic() + duration_s
    t0 = time.monotonic()
    try:
        while time.monotonic() < t_end:
            t_read = time.monotonic()
            try:
                reading = await robot.read_joints()
            except DeviceError as exc:
                failed += 1
                errors[type(exc).__name__] = errors.get(type(exc).__name__, 0) + 1
                await asyncio.sleep(0.01)
                continue
            finally:
                longest_s = max(longest_s, time.monotonic() - t_read)
            ok += 1
            if (
                max(abs(a - b) for a, b in zip(reading.joints_deg, truth, strict=True))
                > (TOLERANCE_DEG[kind])
            ):
                wrong += 1
    finally:
        await robot.close()
    elapsed = time.monotonic() - t0
    return {
        "reads_per_s": round(ok / elapsed, 1),
        "success_rate": round(ok / max(ok + failed, 1), 4),
        "ok": ok,
        "failed": failed,
        "wrong": wrong,
        "reconnects": max(connects - 1, 0),
        "longest_read_s": round(longest_s, 3),
        "errors": errors,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", help="checkout whose drivers/ and simulator/ to measure")
    parser.add_argument("--duration-s", type=float, default=DURATION_S)
    parser.add_argument("--out", help="also write the results as a Markdown table here")
    parser.add_argument("--kinds", default=",".join(KINDS), help="comma-separated kinds")
    args = parser.parse_args()
    import os

    # The EMULATED ABB face accepts ABB's factory-default login.
    os.environ.setdefault("CABLECAL_ROBOT_PASSWORD", "robotics")
    if args.root:
        sys.path.insert(0, args.root)
    from simulator.config import SimConfig
    from simulator.runner import SimulatorThread

    ports = {"port": 0}
    config = SimConfig.model_validate(
        {"seed": 11, "robot_socketcmd": ports, "robot_modbus": ports, "control": ports}
    )

    results: dict[str, Any] = {}
    for kind in args.kinds.split(","):
        for rate in DROP_RATES:
            with SimulatorThread(config) as sim:
                sim.control("hold", on=True)
                sim.control("fault", robot_drop_rate=rate)
                results[f"{kind} drop {rate:.0%}"] = asyncio.run(_run(kind, sim, args.duration_s))
    print(json.dumps(results, indent=1))
    if args.out:
        _write_markdown(results, args.out, args.duration_s)


def _write_markdown(results: dict[str, Any], path: str, duration_s: float) -> None:
    import os
    import platform

    lines = [
        "# Robot links: joint reads over a lossy link",
        "",
        f"`python -m bench.robot_link_bench --out {path}`: each driver reads back to back for "
        f"{duration_s:g} s from the EMULATED cell (robot held still) with its default settings, "
        "at 0 % and 10 % emulated dropped replies (RTDE: dropped data packages). "
        f"Machine: {platform.machine()}, {os.cpu_count()} CPUs, load average "
        f"{os.getloadavg()[0]:.1f} at the end (shared with other jobs).",
        "",
        "| driver, drops | reads/s | success | wrong values | reconnects | longest read [s] |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for name, r in results.items():
        lines.append(
            f"| {name} | {r['reads_per_s']} | {r['success_rate']:.2%} | {r['wrong']} | "
            f"{r['reconnects']} | {r['longest_read_s']} |"
        )
    lines += [
        "",
        "A UR RTDE read returns the latest data package when it was generated at most one "
        "stream period (8 ms at 125 Hz) before the read began, without a round trip: back-to-"
        "back reads return the same package many times; new values come at the stream's "
        "125/s. With 10 % of the RTDE packages dropped no read fails (the next package is "
        "8 ms away); the round-trip drivers lose one fast_reply_timeout_s (0.2 s) per drop.",
        "",
    ]
    with open(path, "w", encoding="utf-8") as f:
        f.write("\n".join(lines))


if __name__ == "__main__":
    main()
