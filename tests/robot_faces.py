"""Helpers of the brand-face tests (KUKA VarProxy, FANUC RMI): how far a joint reading is
from the emulated cell's truth, and the fault checks both faces' drivers must pass (they share
drivers/robot_link.py): each drives a driver through one fault of the emulated cell."""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import Sequence
from typing import Any

import numpy as np
import pytest

from drivers import RobotError, RobotLinkDown, RobotStale
from simulator.runner import SimulatorThread


def deviation_from_truth_deg(
    sim: SimulatorThread, joints_deg: Sequence[float], t_from_s: float, t_to_s: float
) -> float:
    """``min_t max_j |q_j(t) - reading_j|`` [deg] for t in [t_from_s, t_to_s] (monotonic
    seconds): how far a reading is from the cell's truth at any instant of that span (0.5 ms
    grid, then 0.01 ms around the best instant)."""
    reading = np.asarray(joints_deg, dtype=float)

    def best(times_s: np.ndarray) -> tuple[float, float]:
        devs = [float(np.abs(sim.cell.reported_joints(t) - reading).max()) for t in times_s]
        k = int(np.argmin(devs))
        return float(times_s[k]), devs[k]

    t_best, _ = best(np.arange(t_from_s - 0.001, t_to_s + 0.0005, 0.0005))
    return best(np.arange(t_best - 0.0006, t_best + 0.0006, 0.00001))[1]


def last_tx_s(frames: Sequence[str]) -> float:
    """Monotonic time [s] of the last frame sent, from a driver's frame log."""
    return max(float(line.split()[0]) for line in frames if " tx " in line)


async def drops_and_late_replies(sim: SimulatorThread, robot: Any, resolution_deg: float) -> None:
    """10 % dropped and 10 % late replies: every value returned is the truth; failures are
    typed RobotErrors; single drops cost no reconnect; late replies are not taken."""
    truth = np.asarray(sim.control("state")["joints_deg"])
    sim.control("fault", robot_drop_rate=0.1, robot_late_rate=0.1, robot_late_delay_s=0.3)
    good: list[tuple[float, ...]] = []
    errors: list[RobotError] = []
    try:
        for _ in range(40):
            try:
                good.append((await robot.read_joints()).joints_deg)
            except RobotError as exc:
                errors.append(exc)
    finally:
        await robot.close()
    assert robot.attempts.silent_total >= 4, robot.attempts.silent_total  # faults exercised
    assert len(good) >= 37, [str(e) for e in errors]
    assert np.abs(np.asarray(good) - truth).max() <= resolution_deg
    assert robot.late_discarded >= 2  # late replies came and were not taken


async def late_replies_never_taken(sim: SimulatorThread, robot: Any, resolution_deg: float) -> None:
    """Robot always moving, 20 % of replies 0.3 s late (after the 0.2 s first wait): each
    reading is the truth at an instant between its request and its stamp (a late reply taken
    for the retry's would be 0.2 s older: degrees away)."""
    sim.control("fault", robot_late_rate=0.2, robot_late_delay_s=0.3)
    checked = []
    try:
        for _ in range(30):
            reading = await robot.read_joints()
            checked.append((reading, last_tx_s(robot.frames.snapshot())))
    finally:
        await robot.close()
    assert robot.attempts.recovered_total >= 2  # late replies were in flight
    for reading, t_tx_s in checked:
        dev = deviation_from_truth_deg(sim, reading.joints_deg, t_tx_s, reading.t_monotonic_s)
        assert dev <= resolution_deg + 0.01, f"{reading} is {dev:.3f} deg from the truth"


async def link_down_then_back(
    sim: SimulatorThread, robot: Any, target: str, resolution_deg: float
) -> None:
    """The face's link down for 0.5 s: a typed RobotLinkDown, then one reconnect and the truth."""
    try:
        await robot.read_joints()
        sim.control("link_down", target=target, duration_s=0.5)
        with pytest.raises(RobotLinkDown):
            await robot.read_joints()
        t0 = time.monotonic()
        while True:
            with contextlib.suppress(RobotLinkDown):
                reading = await robot.read_joints()
                break
            assert time.monotonic() - t0 < 5, robot.frames.snapshot()
            await asyncio.sleep(0.05)
    finally:
        await robot.close()
    truth = np.asarray(sim.control("state")["joints_deg"])
    assert np.abs(np.asarray(reading.joints_deg) - truth).max() <= resolution_deg
    assert robot.connects == 2


async def frozen_joints_raise_stale(sim: SimulatorThread, robot: Any) -> None:
    """The controller frozen while the robot moves: after ``max_unchanged_s`` (0.2 s) of
    identical joints the driver says RobotStale ("unchanged")."""
    sim.control("hold", on=False)
    sim.control("fault", robot_frozen=True)
    try:
        await robot.read_joints()
        await asyncio.sleep(0.3)
        with pytest.raises(RobotStale, match="unchanged"):
            await robot.read_joints()
    finally:
        await robot.close()
