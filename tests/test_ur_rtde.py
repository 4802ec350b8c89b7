"""UR RTDE (issue 18): the emulated face read by UR's public client (ur_rtde's
``RTDEReceiveInterface``) and by our driver, with faults.

ur_rtde's binding keeps the GIL while it blocks, which would stop the emulated cell's event
loop (a thread of this process), so it runs in a subprocess. Its face listens on port 30004
of a loopback address of its own (``host = "auto"``: the first free of 127.0.0.2 …).
"""

from __future__ import annotations

import asyncio
import json
import subprocess
import sys
import time
from collections.abc import Iterator

import numpy as np
import pytest
from helpers import deviation_from_truth_deg, host_port, start_emulated_cell

from drivers import RobotStale, UrRtdeConfig, UrRtdeRobot
from drivers.errors import DeviceError
from simulator.faces.ur_rtde import UrRtdeServer
from simulator.runner import SimulatorThread

pytestmark = pytest.mark.anyio

#: A reading of the brand's client must match the emulated truth to this [deg].
AGREE_DEG = 0.01

CLIENT = """
import json, sys, time
import rtde_receive

r = rtde_receive.RTDEReceiveInterface(sys.argv[1], 125.0)
rows = []
for _ in range(25):
    time.sleep(0.02)
    t_before, q, t_after = r.getTimestamp(), r.getActualQ(), r.getTimestamp()
    rows.append([t_before, q, t_after, r.getRobotMode(), r.getSafetyMode()])
r.disconnect()
print(json.dumps(rows))
"""


@pytest.fixture
def moving_cell() -> Iterator[SimulatorThread]:
    """Emulated cell whose robot always moves (no dwell): a stale value differs from truth.
    (Peak joint speeds stay below ~500 deg/s, so the 5 µs grid of :func:`_deviation_deg`
    resolves 0.005 deg; a package 0.1 s stale is degrees off.)"""
    s = start_emulated_cell(robot={"move_time_s": 4.0, "dwell_s": 0.0}, indicator={"pty": False})
    try:
        yield s
    finally:
        s.stop()


def _face(sim: SimulatorThread) -> UrRtdeServer:
    assert sim.runner is not None
    face = sim.runner.faces["robot_ur_rtde"]
    assert isinstance(face, UrRtdeServer)
    return face


def test_ur_rtde_client_reads_the_emulated_truth(moving_cell: SimulatorThread) -> None:
    """ur_rtde's RTDEReceiveInterface (its default recipe of 58 variables) against the face
    on port 30004: each ``actual_q`` equals the cell's truth to 0.01 deg while the robot
    moves, at an instant of the controller ``timestamp`` read just before (less one stream
    period: the client's getters are not one atomic snapshot) and just after it."""
    host, port = host_port(moving_cell.ready["robot_ur_rtde"])
    assert port == 30004 and host.startswith("127.0.0.") and host != "127.0.0.1"
    done = subprocess.run(
        [sys.executable, "-c", CLIENT, host], capture_output=True, text=True, timeout=60
    )
    assert done.returncode == 0, done.stderr
    rows = json.loads(done.stdout)
    face = _face(moving_cell)
    period_s = 1 / 125
    errors = [
        deviation_from_truth_deg(
            moving_cell, tuple(np.degrees(q)), face.t0 + t0 - period_s, face.t0 + t1
        )
        for t0, q, t1, _, _ in rows
    ]
    assert max(errors) <= AGREE_DEG, errors
    spread = np.ptp([q for _, q, _, _, _ in rows], axis=0).max()
    assert np.degrees(spread) > 1.0  # the robot did move: the check is not vacuous
    assert {(mode, safety) for *_, mode, safety in rows} == {(7, 1)}  # RUNNING, NORMAL


def _robot(sim: SimulatorThread, **cfg: float) -> UrRtdeRobot:
    host, port = host_port(sim.ready["robot_ur_rtde"])
    return UrRtdeRobot(UrRtdeConfig(host=host, port=port, **cfg))


async def test_driver_under_drops_and_late_packages_returns_only_fresh_truth(
    moving_cell: SimulatorThread,
) -> None:
    """20 % of data packages dropped, 5 % held back 0.1 s (arriving with old data): every
    reading is the truth at an instant between one stream period (plus 10 ms: the driver dates
    packages by the least-delayed one, and loopback latency on a loaded machine is a few ms)
        before the read began and its stamp; a held-back package taken as fresh would be 0.1 s
    stale (degrees off)."""
    moving_cell.control("fault", robot_drop_rate=0.2, robot_late_rate=0.05, robot_late_delay_s=0.1)
    robot = _robot(moving_cell)
    period_s = 1.0 / robot.config.frequency_hz
    checked = []
    try:
        for _ in range(15):
            t_asked = time.monotonic()
            reading = await robot.read_joints()
            checked.append((reading, t_asked))
            await asyncio.sleep(0.05)
    finally:
        await robot.close()
    for reading, t_asked in checked:
        dev = deviation_from_truth_deg(
            moving_cell, reading.joints_deg, t_asked - period_s - 0.01, reading.t_monotonic_s
        )
        assert dev <= 0.002, f"{reading} is {dev:.4f} deg from the truth"
    assert robot.late_packages >= 3  # the fault was exercised


async def test_driver_recovers_after_link_down_and_flags_frozen_joints(
    moving_cell: SimulatorThread,
) -> None:
    robot = _robot(moving_cell, max_unchanged_s=0.3)
    try:
        await robot.read_joints()
        moving_cell.control("link_down", target="robot_ur_rtde", duration_s=0.4)
        failures: list[str] = []
        t_end = time.monotonic() + 3.0
        while time.monotonic() < t_end:
            try:
                reading = await robot.read_joints()
            except DeviceError as exc:
                failures.append(type(exc).__name__)
                await asyncio.sleep(0.05)
                continue
            if failures:
                break
        assert failures and set(failures) <= {"RobotLinkDown", "RobotTimeout"}, failures
        assert robot.connects == 2
        truth = moving_cell.cell.reported_joints(reading.t_monotonic_s)
        assert np.abs(truth - reading.joints_deg).max() < 1.0  # fresh, after the link-down
        moving_cell.control("fault", robot_frozen=True)
        with pytest.raises(RobotStale):
            for _ in range(100):
                await robot.read_joints()
                await asyncio.sleep(0.01)
    finally:
        await robot.close()
