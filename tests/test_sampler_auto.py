"""The sampler's auto mode: each new settled pose captured once, known poses skipped after a
restart, one rejection per error episode, a failing store retried; and auto capture against
the emulated cell, checked against the cell's truth."""

from __future__ import annotations

import asyncio
from typing import Any

import numpy as np
import pytest
from helpers import sim_config
from sampler_fakes import (
    FakeIndicator,
    FakeRobot,
    FakeSink,
    length_is,
    running,
    wait_until,
)

from daemon.sampler.capture import Capture
from daemon.sampler.config import SamplerConfig
from daemon.sampler.core import build_sampler
from drivers import IndicatorLinkDown
from simulator.runner import SimulatorThread

pytestmark = pytest.mark.anyio


# --------------------------------------------------------------------------- auto mode
POSES = [
    (0.0, -30.0, 60.0, 0.0, 45.0, 10.0),
    (20.0, -20.0, 50.0, 5.0, 40.0, 0.0),
    (40.0, -10.0, 40.0, 10.0, 35.0, -10.0),
    (-20.0, -40.0, 70.0, -5.0, 50.0, 20.0),
    (-40.0, -35.0, 65.0, -10.0, 55.0, 30.0),
]


async def test_auto_mode_captures_each_new_pose_once() -> None:
    ind, rob, sink = FakeIndicator(noise_mm=0.01), FakeRobot(joints=POSES[0]), FakeSink()
    async with running(ind, rob, sink) as s:
        s.set_auto(9, anchor="C")
        assert s.status()["sampler"]["mode"] == "auto"
        for i, pose in enumerate([*POSES, POSES[1]]):  # five poses, then one revisited
            if i:
                rob.move_to(pose)
                ind.length_mm += 10.0
            if i < len(POSES):
                await wait_until(length_is(sink.captures, i + 1))
            else:
                await wait_until(lambda: any(r[1] == "not_new_pose" for r in sink.rejections))
            await asyncio.sleep(4 * s.config.settle_s)  # staying put: no second capture
            assert len(sink.captures) == min(i + 1, len(POSES))
        status = s.status()["sampler"]
        s.set_auto(None)
        assert s.status()["sampler"]["mode"] == "manual"
    assert status["auto_campaign_id"] == 9 and status["auto_known_poses"] == 5
    assert len(sink.captures) == 5
    # A window may hold the last ~0.0005 deg of a move (a poll late on a loaded machine):
    # the settle rule's own bound, far below the 20 deg between poses.
    tol_deg = SamplerConfig().settle_tol_deg
    for (cid, cap), pose in zip(sink.captures, POSES, strict=True):
        assert cid == 9 and cap.mode == "auto" and cap.anchor == "C"
        assert np.allclose(cap.joints_deg, pose, atol=tol_deg)
    assert [r[1] for r in sink.rejections] == ["not_new_pose"]


async def test_auto_mode_skips_known_poses_after_a_restart() -> None:
    ind, rob, sink = FakeIndicator(), FakeRobot(joints=POSES[2]), FakeSink()
    async with running(ind, rob, sink) as s:
        with pytest.raises(ValueError, match="known_poses_deg"):
            s.set_auto(5, known_poses_deg=np.zeros((2, 5)))
        s.set_auto(5, known_poses_deg=np.array(POSES[:3]) + 0.01)  # within auto_new_pose_deg
        await wait_until(lambda: bool(sink.rejections))
        await asyncio.sleep(3 * s.config.settle_s)
        assert not sink.captures and [r[1] for r in sink.rejections] == ["not_new_pose"]
        rob.move_to(POSES[3])
        await wait_until(lambda: len(sink.captures) == 1)


async def test_auto_mode_records_one_rejection_per_error_episode() -> None:
    ind, rob, sink = FakeIndicator(name="ind-auto"), FakeRobot(joints=POSES[0]), FakeSink()
    async with running(ind, rob, sink) as s:
        s.set_auto(7)
        await wait_until(lambda: len(sink.captures) == 1)
        ind.error = IndicatorLinkDown("ind-auto", "port vanished")
        rob.move_to(POSES[1])
        await wait_until(lambda: bool(sink.rejections))
        await asyncio.sleep(0.6)  # many failed polls, still one record
        assert [r[1:4:2] for r in sink.rejections] == [("indicator_error", "ind-auto")]
        ind.error = None
        await wait_until(lambda: len(sink.captures) == 2)  # the pose reached meanwhile
        ind.error = IndicatorLinkDown("ind-auto", "port vanished again")
        await wait_until(lambda: len(sink.rejections) == 2)  # a new episode, a new record
        await asyncio.sleep(0.3)
    assert len(sink.rejections) == 2 and len(sink.captures) == 2


class FailingSink(FakeSink):
    def __init__(self, failures: int) -> None:
        super().__init__()
        self.failures = failures

    def store_capture(self, campaign_id: int, capture: Capture) -> dict[str, Any]:
        if self.failures:
            self.failures -= 1
            raise RuntimeError("database is locked")
        return super().store_capture(campaign_id, capture)


async def test_auto_mode_survives_a_failing_store_and_retries() -> None:
    ind, rob, sink = FakeIndicator(), FakeRobot(), FailingSink(failures=2)
    async with running(ind, rob, sink) as s:
        s.set_auto(1)
        await wait_until(lambda: len(sink.captures) == 1)
        await asyncio.sleep(3 * s.config.settle_s)
        assert s.running and len(sink.captures) == 1 and sink.failures == 0
    failed = [e for e in sink.events if e[0] == "capture_failed"]
    assert len(failed) == 2 and "database is locked" in failed[0][2], sink.events


# --------------------------------------------------------------------------- emulated cell
async def test_auto_capture_on_the_emulated_cell_matches_its_truth() -> None:
    sim = SimulatorThread(
        sim_config(
            indicator={"baud": 115200},
            robot={"move_time_s": 0.3, "dwell_s": 0.8, "n_poses": 6},
        )
    ).start()
    try:
        endpoint = sim.ready["robot_socketcmd"]
        assert endpoint is not None
        host, port = endpoint.rsplit(":", 1)
        sink = FakeSink()
        sampler = build_sampler(
            {"port": sim.ready["indicator_port"], "baud": 115200},
            {"kind": "huashu-socketcmd", "host": host, "port": int(port)},
            SamplerConfig(settle_s=0.4),
            sink,
        )
        await sampler.start()
        try:
            sampler.set_auto(1)
            await asyncio.sleep(8.0)
            status = sampler.status()
        finally:
            await sampler.stop()
        truth = sim.control("truth")
        poses = np.array(sim.control("poses")["poses_deg"])
        joints = [list(c.joints_deg) for _, c in sink.captures]
        true = sim.control("true_lengths", joints_deg=joints)["lengths_mm"] if joints else []
    finally:
        sim.stop()
    tol = 3 * truth["noise_mm"] + 0.5 * 10 ** -truth["decimals"]
    # At a dwell, not between: within the settle rule's own bound (a window may hold a
    # reading of a move's last ~0.01 deg, 1e-3 deg in its mean, seen on a loaded machine).
    tol_deg = SamplerConfig().settle_tol_deg
    assert 4 <= len(sink.captures) <= 6, [c.joints_deg for _, c in sink.captures]
    seen = set()
    for (_, cap), length in zip(sink.captures, true, strict=True):
        assert abs(cap.length_mm - length) <= tol
        index = int(np.argmin(np.abs(poses - np.array(cap.joints_deg)).max(axis=1)))
        assert np.allclose(cap.joints_deg, poses[index], atol=tol_deg)
        assert index not in seen  # never the same pose twice
        seen.add(index)
        assert cap.count >= 5 and cap.length_std_mm < 5 * truth["noise_mm"]
    for role in ("indicator", "robot"):
        assert status["devices"][role]["poll_rate_hz"] > 10
    assert not any(r[1] in ("indicator_error", "robot_error") for r in sink.rejections)


async def test_a_loop_of_manual_captures_does_not_starve_auto_capture() -> None:
    """Issue 21: manual captures back to back into one campaign while auto capture runs on
    another (0 auto samples in 30 s before): auto still captures each new pose."""
    ind, rob, sink = FakeIndicator(noise_mm=0.01), FakeRobot(joints=POSES[0]), FakeSink()
    async with running(ind, rob, sink) as s:
        s.set_auto(9, anchor="A")
        manual = 0

        async def manual_loop() -> None:
            nonlocal manual
            while True:
                await s.capture(1, anchor="M")
                manual += 1

        task = asyncio.create_task(manual_loop())
        try:
            await wait_until(lambda: manual >= 2)
            for i, pose in enumerate(POSES[1:4], start=2):
                rob.move_to(pose)
                ind.length_mm += 10.0
                await wait_until(
                    lambda i=i: sum(c == 9 for c, _ in sink.captures) >= i  # type: ignore[misc]
                )
            n_manual = manual
            await wait_until(lambda: manual > n_manual + 1)  # and manual keeps going
        finally:
            task.cancel()
            with pytest.raises(asyncio.CancelledError):
                await task
    auto = [cap for cid, cap in sink.captures if cid == 9]
    assert [cap.mode for cap in auto] == ["auto"] * 4
    # a window may hold the last ~0.01 deg of a move: the settle rule's own bound
    tol_deg = SamplerConfig().settle_tol_deg
    for cap, pose in zip(auto, POSES[:4], strict=True):
        assert np.allclose(cap.joints_deg, pose, atol=tol_deg)
