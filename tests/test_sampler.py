"""The sampler: capture statistics, rejections with their reasons, the manual robot, device
events and status, on scripted devices (sampler_fakes.py). Settle verdicts themselves are
tested without asyncio in test_settle.py; auto mode in test_sampler_auto.py."""

from __future__ import annotations

import asyncio
import logging
import math
import time

import numpy as np
import pytest
from sampler_fakes import (
    FAST,
    HOME,
    FakeIndicator,
    FakeRobot,
    FakeSink,
    metric,
    running,
    wait_until,
)

from daemon.sampler.capture import CaptureRejected
from daemon.sampler.config import SamplerConfig
from daemon.sampler.core import Sampler, build_sampler
from drivers import (
    AsciiIndicator,
    HuashuSocketCmdRobot,
    IndicatorCRCError,
    IndicatorLinkDown,
    IndicatorOverRange,
    ManualRobot,
    ModbusIndicator,
    RobotTimeout,
)
from drivers.robot import JointReading

pytestmark = pytest.mark.anyio


# --------------------------------------------------------------------------- configuration
def test_config_is_strict_and_checked() -> None:
    with pytest.raises(ValueError, match="settle_window"):
        SamplerConfig.model_validate({"settle_window": 1})
    with pytest.raises(ValueError, match="capture_timeout_s"):
        SamplerConfig(settle_s=2.0, capture_timeout_s=1.0)
    with pytest.raises(ValueError, match="min_readings"):
        SamplerConfig(min_readings=1)
    for name, f in SamplerConfig.model_fields.items():
        assert f.description and "[" in f.description, name  # documented, with its unit
    assert SamplerConfig().poll_interval_s == 0.0


def test_build_sampler_uses_the_driver_factories() -> None:
    sink = FakeSink()
    s = build_sampler({"port": "/dev/null-none"}, {"kind": "manual"}, None, sink)
    assert isinstance(s.indicator, ModbusIndicator) and isinstance(s.robot, ManualRobot)
    assert s.manual_robot and s.mode == "manual" and not s.running
    s2 = build_sampler(
        {"kind": "ascii", "port": "/dev/null-none"},
        {"kind": "huashu-socketcmd", "host": "127.0.0.1", "port": 1},
        {"settle_s": 0.3},
        sink,
    )
    assert isinstance(s2.indicator, AsciiIndicator)
    assert isinstance(s2.robot, HuashuSocketCmdRobot)
    assert s2.config.settle_s == 0.3
    with pytest.raises(ValueError, match="kind"):
        build_sampler({}, {"kind": "kuka"}, None, sink)


# --------------------------------------------------------------------------- settling
async def test_still_robot_with_noise_within_tolerance_settles_and_drift_does_not() -> None:
    ind, rob, sink = FakeIndicator(noise_mm=0.01), FakeRobot(), FakeSink()
    async with running(ind, rob, sink) as s:
        await wait_until(lambda: s.status()["sampler"]["settled"])
        rob.drift_deg_s = 1.0  # 0.1 deg per window >> settle_tol_deg
        await wait_until(lambda: not s.status()["sampler"]["settled"])
        assert s.status()["sampler"]["settle_state"] == "moving"
        rob.drift_deg_s = 0.0
        rob.move_to(HOME, move_s=0.0)
        await wait_until(lambda: s.status()["sampler"]["settled"])
        ind.noise_mm = 0.5  # length noise beyond settle_tol_mm: not settled
        await wait_until(lambda: not s.status()["sampler"]["settled"])
        assert "cable length" in s.status()["sampler"]["settle_detail"]


async def test_capture_is_the_mean_of_a_settled_window_after_the_request() -> None:
    ind, rob, sink = FakeIndicator(noise_mm=0.02), FakeRobot(), FakeSink()
    before = metric("cablecal_captures_total", outcome="accepted", reason="ok", mode="manual")
    async with running(ind, rob, sink) as s:
        await wait_until(lambda: s.status()["sampler"]["settled"])
        t_request = time.time()
        row = await s.capture(3, anchor="B")
        assert row == {"id": 1, "campaign_id": 3, "length_mm": sink.captures[0][1].length_mm}
        second = await s.capture(3)  # never reuses the readings of the first
    (cid, cap), (_, cap2) = sink.captures
    assert cid == 3 and cap.anchor == "B" and cap.mode == "manual" and second["id"] == 2
    lengths = np.array([r.length_mm for r in cap.raw])
    joints = np.array([r.joints_deg for r in cap.raw])
    assert cap.count == len(cap.raw) >= s.config.min_readings
    assert cap.length_mm == pytest.approx(lengths.mean(), abs=1e-12)
    assert cap.length_std_mm == pytest.approx(lengths.std(ddof=1), abs=1e-12)
    assert cap.length_std_mm == pytest.approx(0.02, rel=0.8)
    assert np.allclose(cap.joints_deg, HOME) and np.allclose(cap.joints_std_deg, 0.0)
    assert np.allclose(joints, HOME)
    assert cap.t_start_wall == cap.raw[0].t_wall <= cap.t_end_wall == cap.raw[-1].t_wall
    assert cap.raw[0].t_wall >= t_request  # no reading from before the call
    assert cap.t_end_wall - cap.t_start_wall <= s.config.settle_s + 1e-6
    assert cap2.raw[0].t_wall > cap.raw[-1].t_wall
    after = metric("cablecal_captures_total", outcome="accepted", reason="ok", mode="manual")
    assert after == before + 2


# --------------------------------------------------------------------------- rejections
@pytest.mark.parametrize("cause", ["joints_drift", "length_noise"])
async def test_manual_capture_times_out_as_moving(cause: str) -> None:
    ind, rob, sink = FakeIndicator(), FakeRobot(), FakeSink()
    if cause == "joints_drift":
        rob.drift_deg_s = 2.0
    else:
        ind.noise_mm = 1.0
    before = metric("cablecal_captures_total", outcome="rejected", reason="moving", mode="manual")
    # A window of 0.3 s needing 3 readings, stale only after a 1 s gap: a loaded machine's
    # slow polls (a 0.1 s window fell short of 5 readings here at load 12) still fill every
    # window, so the last verdict before the timeout is the motion's, not "stale".
    settings = {"capture_timeout_s": 1.0, "settle_s": 0.3, "min_readings": 3, "stale_s": 1.0}
    async with running(ind, rob, sink, **settings) as s:
        t0 = time.monotonic()
        with pytest.raises(CaptureRejected) as info:
            await s.capture(1)
        assert time.monotonic() - t0 >= 1.0
    assert info.value.reason == "moving" and info.value.http_status == 409
    assert "capture_timeout_s" in info.value.detail
    assert sink.rejections == [(1, "moving", info.value.detail, None)] and not sink.captures
    after = metric("cablecal_captures_total", outcome="rejected", reason="moving", mode="manual")
    assert after == before + 1


@pytest.mark.parametrize("role", ["indicator", "robot"])
async def test_failing_device_rejects_with_503_naming_it_and_its_error(role: str) -> None:
    ind, rob, sink = FakeIndicator(name="hy9648"), FakeRobot(name="hsr-jr680"), FakeSink()
    async with running(ind, rob, sink, capture_timeout_s=8.0) as s:
        await wait_until(lambda: s.status()["sampler"]["settled"])
        if role == "indicator":
            ind.error = IndicatorLinkDown("hy9648", "cannot open /dev/ttyUSB9", ["tx 01 03"])
        else:
            rob.error = RobotTimeout("hsr-jr680", "no reply within 1.0 s", ["tx i:7,c:x@hs@"])
        t0 = time.monotonic()
        with pytest.raises(CaptureRejected) as info:
            await s.capture(2)
        assert time.monotonic() - t0 < 5.0  # fails fast, does not wait for the timeout
        status = s.status()["devices"][role]
    exc = info.value
    name = "hy9648" if role == "indicator" else "hsr-jr680"
    assert exc.reason == f"{role}_error" and exc.http_status == 503 and exc.device == name
    assert name in exc.detail
    assert ("cannot open /dev/ttyUSB9" if role == "indicator" else "no reply") in exc.detail
    assert sink.rejections[-1][1:] == (exc.reason, exc.detail, name)
    assert status["state"] == "error" and not status["connected"]
    assert status["last_error"]["frames_hex"] and status["errors"] >= 1


#: The robot's pose in the over-range test [deg]: not the fakes' home, so the refusal's pose is
#: the robot's.
POSE_OR = (12.5, -30.0, 45.0, 0.0, 60.0, -90.0)


async def test_over_range_is_rejected_whether_flagged_or_raised() -> None:
    ind, rob, sink = FakeIndicator(name="ind-or"), FakeRobot(joints=POSE_OR), FakeSink()
    ind.over_range = True  # over_range_policy = "flag"
    async with running(ind, rob, sink) as s:
        t0 = time.monotonic()
        with pytest.raises(CaptureRejected) as info:
            await s.capture(1)
        assert info.value.reason == "over_range" and info.value.http_status == 409
        assert time.monotonic() - t0 < s.config.capture_timeout_s  # robot still: no waiting
        ind.over_range = False
        ind.error = IndicatorOverRange("ind-or", "status 0x0001: over/under-range")  # "raise"
        with pytest.raises(CaptureRejected) as info:
            await s.capture(1)
        assert info.value.reason == "over_range"
        ind.error = None
        await s.capture(1)  # in range again
    assert [r[1] for r in sink.rejections] == ["over_range", "over_range"]
    # Each refusal is handed to the sink with the robot's pose (a plan's progress reads it).
    assert sink.rejection_poses == [POSE_OR, POSE_OR]
    # Over-range is counted as a failed poll but is no link event.
    assert metric(
        "cablecal_device_errors_total",
        device="ind-or",
        role="indicator",
        error="IndicatorOverRange",
    )
    assert sink.kinds("ind-or") == []


@pytest.mark.parametrize("lagging", ["robot", "indicator"])
async def test_stale_stamps_are_rejected(lagging: str) -> None:
    ind, rob, sink = FakeIndicator(), FakeRobot(), FakeSink()
    (rob if lagging == "robot" else ind).lag_s = 1.0
    async with running(ind, rob, sink, capture_timeout_s=0.5) as s:
        with pytest.raises(CaptureRejected) as info:
            await s.capture(1)
    assert info.value.reason == "stale" and info.value.http_status == 503
    assert sink.rejections[0][1] == "stale" and not sink.captures


async def test_no_reading_at_all_is_no_data() -> None:
    ind, rob, sink = FakeIndicator(), FakeRobot(), FakeSink()
    sampler = Sampler(ind, rob, SamplerConfig(**FAST), sink)
    with pytest.raises(CaptureRejected) as info:
        await sampler.capture(1)  # never started
    assert info.value.reason == "no_data" and info.value.http_status == 503


# --------------------------------------------------------------------------- manual robot
async def test_manual_robot_takes_joints_from_the_request() -> None:
    ind, robot, sink = FakeIndicator(noise_mm=0.01), ManualRobot(), FakeSink()
    async with running(ind, robot, sink) as s:
        with pytest.raises(CaptureRejected) as info:
            await s.capture(4)
        assert info.value.reason == "no_data" and "joints_deg" in info.value.detail
        with pytest.raises(ValueError, match="joints_deg"):
            await s.capture(4, joints_deg=[1.0, 2.0])
        row = await s.capture(4, joints_deg=[10, 20, 30, 40, 50, 60])
        row2 = await s.capture(4, joints_deg=[11, 20, 30, 40, 50, 60])
        assert s.status()["devices"]["robot"]["state"] == "ok"
    assert row["id"] == 1 and row2["id"] == 2
    (_, cap), (_, cap2) = sink.captures
    assert cap.joints_deg == (10.0, 20.0, 30.0, 40.0, 50.0, 60.0)
    assert cap2.joints_deg[0] == 11.0 and all(r.joints_deg[0] == 11.0 for r in cap2.raw)
    assert cap.count >= s.config.min_readings


async def test_joints_deg_for_a_robot_that_reports_its_own_is_refused() -> None:
    async with running(FakeIndicator(), FakeRobot(), FakeSink()) as s:
        with pytest.raises(ValueError, match="joints_deg"):
            await s.capture(1, joints_deg=HOME)


# --------------------------------------------------------------------------- events, status
async def test_link_down_and_up_events_metrics_and_logs(caplog: pytest.LogCaptureFixture) -> None:
    ind, rob, sink = FakeIndicator(name="ind-ev"), FakeRobot(name="rob-ev"), FakeSink()
    labels = {"device": "ind-ev", "role": "indicator"}
    caplog.set_level(logging.INFO, logger="cablecal.sampler")
    # the registry is the process's: counted from here (the test may run again in it)
    reconnects_before = metric("cablecal_device_reconnects_total", **labels)
    polls_before = metric("cablecal_device_polls_total", **labels)
    async with running(ind, rob, sink) as s:
        await wait_until(lambda: s.status()["devices"]["indicator"]["polls"] > 3)
        ind.error = IndicatorLinkDown("ind-ev", "cannot open /dev/ttyUSB0", ["connect failed"])
        await wait_until(lambda: s.status()["devices"]["indicator"]["errors"] >= 3)
        down = s.status()["devices"]["indicator"]
        robot_polls_down = s.status()["devices"]["robot"]["polls"]
        ind.error = None
        await wait_until(lambda: s.status()["devices"]["indicator"]["state"] == "ok")
        ind.error = IndicatorCRCError("ind-ev", "CRC mismatch; reply discarded", ["rx 01 03 ff"])
        await wait_until(lambda: sink.kinds("ind-ev")[-1:] == ["device_error"])
        ind.error = None
        await wait_until(lambda: sink.kinds("ind-ev")[-1:] == ["link_up"])
        up = s.status()["devices"]["indicator"]
        # The robot kept delivering while the indicator was down: counted, not timed (its
        # newest reading may be older than settle_s, "late", on a loaded machine).
        robot = s.status()["devices"]["robot"]
        assert robot["connected"] and robot["errors"] == 0 and robot["polls"] > robot_polls_down
    assert sink.kinds("ind-ev") == ["link_down", "link_up", "device_error", "link_up"]
    assert sink.kinds("rob-ev") == []
    link_down = next(e for e in sink.events if e[0] == "link_down")
    assert link_down[3] == {"error": "IndicatorLinkDown", "frames_hex": ["connect failed"]}
    assert down["state"] == "error" and down["last_error"]["class"] == "IndicatorLinkDown"
    assert down["last_error"]["message"] == "cannot open /dev/ttyUSB0"
    assert up["state"] == "ok" and up["errors_by_class"]["IndicatorLinkDown"] >= 3
    assert metric("cablecal_device_reconnects_total", **labels) == reconnects_before + 2
    assert metric("cablecal_device_errors_total", error="IndicatorCRCError", **labels) >= 1
    assert metric("cablecal_device_polls_total", **labels) == polls_before + up["polls"]
    warned = [r for r in caplog.records if r.levelno == logging.WARNING]
    assert warned and all(getattr(r, "device", None) == "ind-ev" for r in warned)
    assert getattr(warned[0], "frames_hex", None) == ["connect failed"]


async def test_a_driver_bug_does_not_stop_the_loop() -> None:
    ind, rob, sink = FakeIndicator(), FakeRobot(name="rob-bug"), FakeSink()
    async with running(ind, rob, sink) as s:
        rob.error = RuntimeError("driver bug")
        await wait_until(lambda: s.status()["devices"]["robot"]["errors"] >= 2)
        rob.error = None
        await wait_until(lambda: s.status()["devices"]["robot"]["state"] == "ok")
        assert s.running
        await s.capture(1)
    assert sink.kinds("rob-bug") == ["device_error", "link_up"]


async def test_a_driver_leaking_cancellation_does_not_stop_the_loop() -> None:
    ind, rob, sink = FakeIndicator(name="ind-cx"), FakeRobot(), FakeSink()
    async with running(ind, rob, sink) as s:
        ind.error = asyncio.CancelledError()
        await wait_until(lambda: s.status()["devices"]["indicator"]["state"] == "error")
        ind.error = None
        await wait_until(lambda: s.status()["devices"]["indicator"]["state"] == "ok")
        assert s.running
    assert sink.kinds("ind-cx") == ["device_error", "link_up"]


async def test_concurrent_captures_use_disjoint_windows() -> None:
    ind, rob, sink = FakeIndicator(noise_mm=0.01), FakeRobot(), FakeSink()
    async with running(ind, rob, sink) as s:
        rows = await asyncio.gather(s.capture(1), s.capture(1))
    assert sorted(r["id"] for r in rows) == [1, 2]
    (_, a), (_, b) = sink.captures
    assert a.raw[-1].t_wall < b.raw[0].t_wall


async def test_status_rates_and_age_metrics() -> None:
    ind, rob, sink = FakeIndicator(name="ind-st"), FakeRobot(name="rob-st"), FakeSink()
    s = Sampler(ind, rob, SamplerConfig(**FAST), sink)
    s.update_age_metrics()
    age = metric("cablecal_last_reading_age_seconds", device="ind-st", role="indicator")
    assert math.isnan(age)
    async with running(ind, rob, sink) as s:
        await wait_until(lambda: s.status()["sampler"]["readings_in_buffer"] > 10)
        await asyncio.sleep(0.2)
        status = s.status()
        s.update_age_metrics()
        t0 = time.perf_counter()
        for _ in range(200):
            s.status()
        per_call_s = (time.perf_counter() - t0) / 200
    assert sink.events[0][0] == "sampler_started"
    dev = status["devices"]["indicator"]
    assert dev["name"] == "ind-st" and dev["role"] == "indicator" and dev["connected"]
    assert dev["poll_rate_hz"] > 5 and dev["last_reading"]["value"] == 500.0
    assert 0 <= dev["last_reading"]["age_s"] < 5 and dev["last_error"] is None
    assert status["devices"]["robot"]["last_reading"]["value"] == list(HOME)
    assert status["sampler"]["mode"] == "manual" and status["sampler"]["running"]
    assert 0 <= metric("cablecal_last_reading_age_seconds", device="rob-st", role="robot") < 5
    assert per_call_s < 0.005  # generous; it is some microseconds
    assert ind.closed and rob.closed


class _CancelSwallowingRobot(FakeRobot):
    """A robot driver whose read swallows a cancel, as Python 3.11's ``asyncio.wait_for``
    (the drivers' per-read timeout) does when the cancel arrives as the read completes: the
    call returns a reading and the task's cancel request stays counted."""

    def __init__(self) -> None:
        super().__init__()
        self.swallowed = 0
        self.reads = 0

    async def read_joints(self) -> JointReading:
        self.reads += 1
        try:  # the first read answers at once, every later one is slow: a cancel lands here
            await asyncio.sleep(0.003 if self.reads == 1 else 10.0)
        except asyncio.CancelledError:
            self.swallowed += 1
        return await super().read_joints()


async def test_stop_ends_the_poll_loops_when_a_driver_swallows_the_cancel() -> None:
    """Regression (intermittent hang of the emulated-cell sampler tests): a cancel lost inside
    a driver call must not keep the poll loop running, so stop() returns."""
    robot = _CancelSwallowingRobot()
    sampler = Sampler(FakeIndicator(), robot, SamplerConfig(**FAST), FakeSink())
    await sampler.start()
    await asyncio.sleep(0.2)
    await asyncio.wait_for(sampler.stop(), timeout=2.0)
    assert robot.swallowed >= 1  # the cancel did land inside the driver's read
