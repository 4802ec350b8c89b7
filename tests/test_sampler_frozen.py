"""Issue 32 item 2: no sample from a controller that does not answer truly. A controller that
keeps answering with bit-identical joints while the robot moves (the emulated cell's
``robot_frozen`` fault) must not give a sample pairing the old joints with the new length:
the capture is refused with a reason in words (``frozen``, 503, naming the robot), the
status says so at once, and captures go on as soon as the controller reports new joints.

First the rule itself on hand-made readings (no clock, no asyncio), then the sampler on the
scripted fakes (sampler_fakes.py)."""

from __future__ import annotations

import asyncio
import math

import numpy as np
import pytest
from sampler_fakes import HOME, FakeIndicator, FakeRobot, FakeSink, running, wait_until

from calib.monitor.settle import FrozenWatch, PairedReading
from daemon.sampler.capture import REJECTION_STATUS, CaptureRejected

TOL_MM = 0.1
N = 5
A = HOME
B = (10.0, -20.0, 70.0, 5.0, 40.0, 20.0)


def _reading(
    t: float, q: tuple[float, ...], length_mm: float, manual: bool = False
) -> PairedReading:
    joints = (q[0], q[1], q[2], q[3], q[4], q[5])
    return PairedReading(t, t, t, joints, length_mm, False, 0.0, math.nan if manual else t)


def _feed(watch: FrozenWatch, readings: list[PairedReading], history_s: float = 10.0) -> None:
    for k, r in enumerate(readings):
        oldest = next(x for x in readings[: k + 1] if x.t_mono >= r.t_mono - history_s)
        watch.add(r, oldest)


def test_joints_still_while_the_cable_moved_are_frozen_until_they_change() -> None:
    watch = FrozenWatch(TOL_MM, N)
    at_a = [_reading(0.01 * k, A, 500.0) for k in range(50)]
    # the robot goes on to B, the controller still says A: the length moves 30 mm
    moving = [_reading(0.5 + 0.01 * k, A, 500.0 + 0.3 * k) for k in range(100)]
    at_b = [_reading(1.5 + 0.01 * k, A, 530.0) for k in range(50)]
    _feed(watch, at_a + moving + at_b)
    verdict = watch.verdict(at_b[-1])
    assert verdict is not None and verdict.reason == "frozen" and verdict.final
    assert "30.0 mm" in verdict.detail and "not updating its joints" in verdict.detail
    # still frozen long after the move left the buffer (the same joints keep coming)
    later = [_reading(12.0 + 0.01 * k, A, 530.0) for k in range(20)]
    _feed(watch, at_a + moving + at_b + later)
    assert watch.verdict(later[-1]) is not None
    # the controller answers again: new joints, no verdict
    thawed = _reading(13.0, B, 530.0)
    watch.add(thawed, later[0])
    assert watch.verdict(thawed) is None


def test_a_true_move_noise_a_slow_drift_and_the_manual_robot_are_not_frozen() -> None:
    # the joints follow the cable: never frozen
    watch = FrozenWatch(TOL_MM, N)
    moves = [_reading(0.01 * k, (k * 0.1, *A[1:]), 500.0 + 0.3 * k) for k in range(100)]
    _feed(watch, moves)
    assert watch.verdict(moves[-1]) is None
    # a robot at rest: noise within the tolerance, and a 0.5 mm thermal drift over 5 minutes
    watch = FrozenWatch(TOL_MM, N)
    rest = [
        _reading(0.1 * k, A, 500.0 + 0.5 * k / 3000 + 0.02 * math.sin(1.7 * k)) for k in range(3000)
    ]
    _feed(watch, rest)
    assert watch.verdict(rest[-1]) is None
    # a single spike is not a move
    watch = FrozenWatch(TOL_MM, N)
    spike = [_reading(0.01 * k, A, 500.0 + (1.0 if k == 40 else 0.0)) for k in range(80)]
    _feed(watch, spike)
    assert watch.verdict(spike[-1]) is None
    # the manual robot's angles are typed in: repeated by design
    watch = FrozenWatch(TOL_MM, N)
    manual = [_reading(0.01 * k, A, 500.0 + 0.3 * k, manual=True) for k in range(100)]
    _feed(watch, manual)
    assert watch.verdict(manual[-1]) is None


@pytest.mark.anyio
async def test_the_sampler_refuses_a_frozen_controller_and_says_so_at_once() -> None:
    ind, rob, sink = FakeIndicator(length_mm=500.0), FakeRobot(joints=A), FakeSink()
    async with running(ind, rob, sink, history_s=5.0) as s:
        await wait_until(lambda: s.status()["sampler"]["settled"])
        # before: a capture at A is taken
        first = await s.capture(1)
        assert first["length_mm"] == pytest.approx(500.0)
        # the controller freezes, the robot moves to B: the cable moves 30 mm in steps
        rob.freeze()
        rob.move_to(B, move_s=0.0)
        for k in range(1, 31):
            ind.length_mm = 500.0 + k
            await asyncio.sleep(0.01)
        await wait_until(lambda: s.status()["sampler"]["settle_state"] == "frozen")
        status = s.status()["sampler"]
        assert not status["settled"] and "not updating its joints" in status["settle_detail"]
        with pytest.raises(CaptureRejected) as info:
            await s.capture(1)
        assert info.value.reason == "frozen" and info.value.http_status == 503
        assert info.value.device == rob.name and "moved by hand" in info.value.detail
        assert len(sink.captures) == 1  # nothing stored with the old joints
        assert sink.rejections[-1][1:] == ("frozen", info.value.detail, rob.name)
        # after: the controller answers again, the capture is taken at B with B's joints
        rob.thaw()
        second = await s.capture(1)
        assert second["length_mm"] == pytest.approx(530.0)
        assert sink.captures[-1][1].joints_deg == pytest.approx(B)


def test_frozen_is_a_rejection_reason_with_its_status() -> None:
    assert REJECTION_STATUS["frozen"] == 503


def test_noise_at_rest_and_a_late_joint_report_as_a_move_starts_are_not_frozen() -> None:
    """The emulated cell's noise (0.35 mm a reading) at rest, and a controller whose joints
    lag the cable by 50 ms as a move starts, gave false ``frozen`` verdicts (4 of 40 plan
    poses lost in the plan end-to-end test): neither is a frozen controller."""
    rng = np.random.default_rng(3)
    watch = FrozenWatch(TOL_MM, N, min_duration_s=0.3)
    rest = [_reading(0.005 * k, A, 500.0 + rng.normal(0.0, 0.35)) for k in range(2000)]
    _feed(watch, rest)
    assert watch.verdict(rest[-1]) is None
    # a move starts: the cable runs at 300 mm/s, the joints follow 50 ms later
    watch = FrozenWatch(TOL_MM, N, min_duration_s=0.3)
    late = [_reading(0.005 * k, A, 500.0 + 1.5 * k) for k in range(10)]
    moving = [_reading(0.05 + 0.005 * k, (k * 0.2, *A[1:]), 515.0 + 1.5 * k) for k in range(100)]
    _feed(watch, late + moving)
    assert all(watch.verdict(r) is None for r in (late[-1], moving[-1]))
    # while a frozen controller still is, after the settle window
    watch = FrozenWatch(TOL_MM, N, min_duration_s=0.3)
    frozen = [_reading(0.005 * k, A, 500.0 + 1.5 * min(k, 60)) for k in range(200)]
    _feed(watch, frozen)
    assert watch.verdict(frozen[-1]) is not None
