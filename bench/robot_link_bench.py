"""Robot joint reads per second and success rate over a lossy link (issue 11, defect 7).

Each robot driver (Huashu SocketCmd, Modbus TCP with the UR preset) reads joint angles back
to back for ``DURATION_S`` from the emulated cell (in-process :class:`SimulatorThread`, robot
held still), with its default configuration, at 0 % and 10 % emulated reply drops
(``robot_drop_rate``). Counted: good reads, failed reads (typed driver errors), reconnects
(successful connects after the first), and wrong reads (a value differing from the cell's
truth by more than the register resolution).

Run from a checkout: ``python -m bench.robot_link_bench`` (prints JSON). To compare with
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
#: Largest |reading - truth| [deg]: Huashu sends 6 decimals, UR registers are 1 mrad.
TOLERANCE_DEG = {"huashu": 1e-5, "modbus": 0.03}


async def _run(kind: str, sim: Any, duration_s: float) -> dict[str, Any]:
    from drivers import DeviceError, make_robot  # the revision under test

    endpoint = sim.ready["robot_socketcmd" if kind == "huashu" else "robot_modbus"]
    host, port = endpoint.rsplit(":", 1)
    cfg = {"kind": "huashu-socketcmd" if kind == "huashu" else "modbus-tcp"}
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
    args = parser.parse_args()
    if args.root:
        sys.path.insert(0, args.root)
    from simulator.config import SimConfig
    from simulator.runner import SimulatorThread

    ports = {"port": 0}
    config = SimConfig.model_validate(
        {"seed": 11, "robot_socketcmd": ports, "robot_modbus": ports, "control": ports}
    )

    results: dict[str, Any] = {}
    for kind in ("huashu", "modbus"):
        for rate in DROP_RATES:
            with SimulatorThread(config) as sim:
                sim.control("hold", on=True)
                sim.control("fault", robot_drop_rate=rate)
                results[f"{kind} drop {rate:.0%}"] = asyncio.run(_run(kind, sim, args.duration_s))
    print(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
