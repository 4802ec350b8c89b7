"""The sampler: settle detection, capture statistics, rejections with their reasons, auto mode
(each pose once), device events; and auto capture against the emulated cell, checked against
the cell's truth."""

from __future__ import annotations

import asyncio
import logging
import math
import time
from collections.abc import AsyncIterator, Callable, Sequence
from contextlib import asynccontextmanager
from typing import Any

import numpy as np
import pytest
from helpers import sim_config
from numpy.typing import NDArray

from daemon import metrics
from daemon.capture import Capture, CaptureRejected
from daemon.sampler import Sampler, SamplerConfig, build_sampler
from drivers import (
    AsciiIndicator,
    HuashuSocketCmdRobot,
    IndicatorCRCError,
    IndicatorLinkDown,
    IndicatorOverRange,
    IndicatorReading,
    JointReading,
    ManualRobot,
    ModbusIndicator,
    RobotTimeout,
)
from simulator.runner import SimulatorThread

pytestmark = pytest.mark.anyio

HOME = (0.0, -30.0, 60.0, 0.0, 45.0, 10.0)
#: Fast settings for the fake devices (they answer every ~5 ms).
FAST: dict[str, Any] = {
    "settle_s": 0.1,
    "stale_s": 0.3,
    "capture_timeout_s": 3.0,
    "error_backoff_s": 0.02,
}


# --------------------------------------------------------------------------- fakes
class FakeIndicator:
    """Scripted indicator: ``length`` plus seeded Gaussian ``noise_mm``; ``error`` is raised
    instead while set; ``lag_s`` back-dates the stamps."""

    def __init__(self, name: str = "ind", length_mm: float = 500.0, noise_mm: float = 0.0) -> None:
        self.name = name
        self.length_mm = length_mm
        self.noise_mm = noise_mm
        self.error: BaseException | None = None
        self.over_range = False
        self.lag_s = 0.0
        self.closed = False
        self._rng = np.random.default_rng(7)

    async def connect(self) -> None:
        pass

    async def read(self) -> IndicatorReading:
        await asyncio.sleep(0.005)
        if self.error is not None:
            raise self.error
        length = self.length_mm + float(self._rng.normal(0.0, self.noise_mm))
        counts = round(length * 100)
        return IndicatorReading(
            length_mm=length,
            counts=counts,
            decimals=2,
            status=1 if self.over_range else 0,
            over_range=self.over_range,
            moving=False,
            t_monotonic_s=time.monotonic() - self.lag_s,
            t_wall=time.time() - self.lag_s,
        )

    async def zero(self) -> None:
        pass

    async def close(self) -> None:
        self.closed = True


class FakeRobot:
    """Scripted robot: at ``joints`` unless moving towards a target (:meth:`move_to`), or
    drifting at ``drift_deg_s`` on joint 1."""

    def __init__(self, name: str = "rob", joints: Sequence[float] = HOME) -> None:
        self.name = name
        self.error: Exception | None = None
        self.lag_s = 0.0
        self.drift_deg_s = 0.0
        self.closed = False
        self._from = np.array(joints, dtype=float)
        self._to = self._from.copy()
        self._t0 = time.monotonic()
        self._move_s = 0.0

    def move_to(self, joints: Sequence[float], move_s: float = 0.15) -> None:
        self._from = self.joints_now()
        self._to = np.array(joints, dtype=float)
        self._t0, self._move_s = time.monotonic(), move_s

    def joints_now(self) -> NDArray[np.float64]:
        t = time.monotonic() - self._t0
        s = 1.0 if self._move_s <= 0 else min(1.0, t / self._move_s)
        q: NDArray[np.float64] = self._from + s * (self._to - self._from)
        q[0] += self.drift_deg_s * t
        return q

    async def connect(self) -> None:
        pass

    async def read_joints(self) -> JointReading:
        await asyncio.sleep(0.003)
        if self.error is not None:
            raise self.error
        q = self.joints_now()
        return JointReading(
            (q[0], q[1], q[2], q[3], q[4], q[5]),
            time.monotonic() - self.lag_s,
            time.time() - self.lag_s,
        )

    async def close(self) -> None:
        self.closed = True


class FakeSink:
    """Records what the sampler hands over, like the store would commit it."""

    def __init__(self) -> None:
        self.captures: list[tuple[int, Capture]] = []
        self.rejections: list[tuple[int | None, str, str, str | None]] = []
        self.events: list[tuple[str, str | None, str, dict[str, Any] | None]] = []

    def store_capture(self, campaign_id: int, capture: Capture) -> dict[str, Any]:
        self.captures.append((campaign_id, capture))
        return {
            "id": len(self.captures),
            "campaign_id": campaign_id,
            "length_mm": capture.length_mm,
        }

    def record_rejection(
        self, campaign_id: int | None, reason: str, detail: str, device: str | None
    ) -> None:
        self.rejections.append((campaign_id, reason, detail, device))

    def record_event(
        self, kind: str, device: str | None, message: str, detail: dict[str, Any] | None = None
    ) -> None:
        self.events.append((kind, device, message, detail))

    def kinds(self, device: str) -> list[str]:
        return [e[0] for e in self.events if e[1] == device]


@asynccontextmanager
async def running(
    indicator: Any, robot: Any, sink: FakeSink, **config: Any
) -> AsyncIterator[Sampler]:
    sampler = Sampler(indicator, robot, SamplerConfig(**{**FAST, **config}), sink)
    await sampler.start()
    try:
        yield sampler
    finally:
        await sampler.stop()


async def wait_until(predicate: Callable[[], bool], timeout_s: float = 10.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError("condition not met in time")
        await asyncio.sleep(0.01)


def length_is(items: Sequence[object], n: int) -> Callable[[], bool]:
    return lambda: len(items) == n


def metric(name: str, **labels: str) -> float:
    return metrics.REGISTRY.get_sample_value(name, labels) or 0.0


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
    async with running(ind, rob, sink, capture_timeout_s=0.6) as s:
        t0 = time.monotonic()
        with pytest.raises(CaptureRejected) as info:
            await s.capture(1)
        assert time.monotonic() - t0 >= 0.6
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


async def test_over_range_is_rejected_whether_flagged_or_raised() -> None:
    ind, rob, sink = FakeIndicator(name="ind-or"), FakeRobot(), FakeSink()
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
    for (cid, cap), pose in zip(sink.captures, POSES, strict=True):
        assert cid == 9 and cap.mode == "auto" and cap.anchor == "C"
        assert np.allclose(cap.joints_deg, pose, atol=1e-9)
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


# --------------------------------------------------------------------------- events, status
async def test_link_down_and_up_events_metrics_and_logs(caplog: pytest.LogCaptureFixture) -> None:
    ind, rob, sink = FakeIndicator(name="ind-ev"), FakeRobot(name="rob-ev"), FakeSink()
    labels = {"device": "ind-ev", "role": "indicator"}
    caplog.set_level(logging.INFO, logger="cablecal.sampler")
    async with running(ind, rob, sink) as s:
        await wait_until(lambda: s.status()["devices"]["indicator"]["polls"] > 3)
        ind.error = IndicatorLinkDown("ind-ev", "cannot open /dev/ttyUSB0", ["connect failed"])
        await wait_until(lambda: s.status()["devices"]["indicator"]["errors"] >= 3)
        down = s.status()["devices"]["indicator"]
        ind.error = None
        await wait_until(lambda: s.status()["devices"]["indicator"]["state"] == "ok")
        ind.error = IndicatorCRCError("ind-ev", "CRC mismatch; reply discarded", ["rx 01 03 ff"])
        await wait_until(lambda: sink.kinds("ind-ev")[-1:] == ["device_error"])
        ind.error = None
        await wait_until(lambda: sink.kinds("ind-ev")[-1:] == ["link_up"])
        up = s.status()["devices"]["indicator"]
        # the robot kept delivering while the indicator was down
        assert s.status()["devices"]["robot"]["state"] == "ok"
    assert sink.kinds("ind-ev") == ["link_down", "link_up", "device_error", "link_up"]
    assert sink.kinds("rob-ev") == []
    link_down = next(e for e in sink.events if e[0] == "link_down")
    assert link_down[3] == {"error": "IndicatorLinkDown", "frames_hex": ["connect failed"]}
    assert down["state"] == "error" and down["last_error"]["class"] == "IndicatorLinkDown"
    assert down["last_error"]["message"] == "cannot open /dev/ttyUSB0"
    assert up["state"] == "ok" and up["errors_by_class"]["IndicatorLinkDown"] >= 3
    assert metric("cablecal_device_reconnects_total", **labels) == 2
    assert metric("cablecal_device_errors_total", error="IndicatorCRCError", **labels) >= 1
    assert metric("cablecal_device_polls_total", **labels) == up["polls"]
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
    assert 4 <= len(sink.captures) <= 6, [c.joints_deg for _, c in sink.captures]
    seen = set()
    for (_, cap), length in zip(sink.captures, true, strict=True):
        assert abs(cap.length_mm - length) <= tol
        index = int(np.argmin(np.abs(poses - np.array(cap.joints_deg)).max(axis=1)))
        assert np.allclose(cap.joints_deg, poses[index], atol=1e-5)  # at a dwell, not between
        assert index not in seen  # never the same pose twice
        seen.add(index)
        assert cap.count >= 5 and cap.length_std_mm < 5 * truth["noise_mm"]
    for role in ("indicator", "robot"):
        assert status["devices"][role]["poll_rate_hz"] > 10
    assert not any(r[1] in ("indicator_error", "robot_error") for r in sink.rejections)
