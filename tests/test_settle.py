"""Settle detection (:mod:`calib.monitor.settle`) and capture building as pure functions:
synthetic buffers and times in, verdicts and captures out; no asyncio, no devices (each
verdict the sampler can reach)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from calib.monitor.settle import NOT_SETTLED, PairedReading, as_joints, evaluate, staleness_s
from daemon.sampler.config import SamplerConfig
from daemon.sampler.settle import make_capture

HOME = (0.0, -30.0, 60.0, 0.0, 45.0, 10.0)
T0 = 1000.0  # monotonic start of the synthetic series [s]
W0 = 1.7e9  # wall time of T0 [s since the epoch]
#: settle_s 0.5 s, stale_s 0.2 s, 5 readings at least, tolerances 0.125 deg / 0.25 mm
#: (powers of two, so boundary cases are exact).
CFG = SamplerConfig(
    settle_s=0.5, stale_s=0.2, min_readings=5, settle_tol_deg=0.125, settle_tol_mm=0.25
)


def series(
    n: int = 21,
    dt_s: float = 0.05,
    length_mm: float = 500.0,
    joints_deg: tuple[float, ...] = HOME,
    t0: float = T0,
) -> list[PairedReading]:
    """``n`` still readings every ``dt_s``, polled at their stamps, not stale."""
    return [
        PairedReading(
            t_poll=t0 + k * dt_s,
            t_mono=t0 + k * dt_s,
            t_wall=W0 + k * dt_s,
            joints_deg=as_joints(joints_deg),
            length_mm=length_mm,
            over_range=False,
            staleness_s=0.01,
        )
        for k in range(n)
    ]


def now_after(buffer: list[PairedReading], age_s: float = 0.01) -> float:
    return buffer[-1].t_mono + age_s


def with_joint(r: PairedReading, joint: int, value_deg: float) -> PairedReading:
    q = list(r.joints_deg)
    q[joint] = value_deg
    return dataclasses.replace(r, joints_deg=as_joints(q))


# --------------------------------------------------------------------------- settled
def test_still_readings_settle_over_the_last_settle_s() -> None:
    buf = series()  # 1.0 s of readings, 0.05 s apart
    verdict = evaluate(buf, CFG, now_after(buf))
    assert verdict.reason is None and verdict.detail == "settled" and verdict.joints_still
    # the window is the readings stamped within settle_s of the newest, oldest first
    assert verdict.window == tuple(r for r in buf if r.t_mono >= buf[-1].t_mono - CFG.settle_s)
    assert len(verdict.window) == 11 and verdict.window[-1] is buf[-1]
    assert not verdict.final


def test_deviations_at_the_tolerances_settle_and_just_above_do_not() -> None:
    buf = series(n=12, dt_s=0.04)  # 0.44 s < settle_s: the whole buffer is the window
    at_tol = [
        dataclasses.replace(
            with_joint(r, 2, 60.0 + (0.25 if k % 2 else 0.0)),
            length_mm=500.0 + (0.5 if k % 2 else 0.0),
        )
        for k, r in enumerate(buf)
    ]  # joint 3 and length alternate: deviation from the mean = exactly the tolerance
    assert evaluate(at_tol, CFG, now_after(at_tol)).reason is None
    over_deg = [
        with_joint(r, 2, r.joints_deg[2] + (1e-6 if k == 1 else 0.0)) for k, r in enumerate(at_tol)
    ]
    verdict = evaluate(over_deg, CFG, now_after(over_deg))
    assert verdict.reason == "moving" and "joint 3" in verdict.detail
    over_mm = [
        dataclasses.replace(r, length_mm=r.length_mm + (1e-6 if k == 1 else 0.0))
        for k, r in enumerate(at_tol)
    ]
    verdict = evaluate(over_mm, CFG, now_after(over_mm))
    assert verdict.reason == "moving" and "cable length" in verdict.detail


# --------------------------------------------------------------------------- no data
def test_empty_buffer_is_no_data() -> None:
    verdict = evaluate([], CFG, T0)
    assert verdict == NOT_SETTLED and verdict.reason == "no_data" and verdict.joints_still is None


def test_newest_reading_polled_before_not_before_is_no_data() -> None:
    buf = series()
    verdict = evaluate(buf, CFG, now_after(buf), not_before=buf[-1].t_poll + 1e-6)
    assert verdict.reason == "no_data"


def test_window_reaching_before_not_before_is_still_collecting() -> None:
    buf = series()
    request = buf[-1].t_mono - 0.3  # 0.3 s of readings since the request < settle_s
    verdict = evaluate(buf, CFG, now_after(buf), not_before=request)
    assert verdict.reason == "moving" and "collecting" in verdict.detail
    request = buf[-1].t_mono - CFG.settle_s - 1e-9  # a whole window after the request
    assert evaluate(buf, CFG, now_after(buf), not_before=request).reason is None


# --------------------------------------------------------------------------- stale
def test_newest_reading_older_than_stale_s_is_stale() -> None:
    buf = series()
    verdict = evaluate(buf, CFG, now_after(buf, age_s=0.25))
    assert verdict.reason == "stale" and "0.25 s old" in verdict.detail
    assert evaluate(buf, CFG, now_after(buf, age_s=0.19)).reason is None


def test_gap_inside_the_window_is_stale() -> None:
    buf = series()
    gapped = buf[:15] + buf[-2:]  # a 0.25 s hole, 2 readings before the newest
    verdict = evaluate(gapped, CFG, now_after(gapped))
    assert verdict.reason == "stale" and "gap of 0.25 s" in verdict.detail


def test_gap_before_the_first_reading_of_the_window_is_stale() -> None:
    # no reading before the window, and the first one comes 0.3 s after its start
    buf = series(n=5, t0=T0 + 0.3)  # newest at T0 + 0.5: the window starts at T0
    verdict = evaluate(buf, CFG, now_after(buf))
    assert verdict.reason == "stale" and "gap" in verdict.detail


def test_too_few_readings_in_the_window_is_stale() -> None:
    buf = series(n=20, dt_s=0.15)  # 0.15 s apart: 4 readings in 0.5 s, min_readings 5
    verdict = evaluate(buf, CFG, now_after(buf))
    assert verdict.reason == "stale" and "fewer than min_readings 5" in verdict.detail
    relaxed = CFG.model_copy(update={"min_readings": 4})
    assert evaluate(buf, relaxed, now_after(buf)).reason is None


def test_a_stale_reading_in_the_window_is_stale_even_when_still() -> None:
    buf = series()
    buf[-3] = dataclasses.replace(buf[-3], staleness_s=0.35)
    verdict = evaluate(buf, CFG, now_after(buf))
    assert verdict.reason == "stale" and "0.35 s old or apart" in verdict.detail
    assert verdict.joints_still is True and not verdict.final
    buf[-3] = dataclasses.replace(buf[-3], staleness_s=0.2)  # at stale_s: not stale
    assert evaluate(buf, CFG, now_after(buf)).reason is None


def test_staleness_of_a_pairing() -> None:
    # robot reports its own stamps: the older stamp's age, or the skew if larger
    assert staleness_s(10.0, 9.9, 9.7, manual_robot=False) == pytest.approx(0.3)
    assert staleness_s(10.0, 9.95, 9.95, manual_robot=False) == pytest.approx(0.05)
    # manual robot: the submission stamp of its angles does not count
    assert staleness_s(10.0, 9.9, 1.0, manual_robot=True) == pytest.approx(0.1)


# --------------------------------------------------------------------------- over-range
def test_over_range_still_is_final_and_moving_is_not() -> None:
    buf = series()
    buf[-4] = dataclasses.replace(buf[-4], over_range=True, length_mm=math.nan)  # raised: no value
    verdict = evaluate(buf, CFG, now_after(buf), device="hy9648")
    assert verdict.reason == "over_range" and "hy9648" in verdict.detail
    assert verdict.final and verdict.joints_still
    moving = [with_joint(r, 0, k * 0.1) for k, r in enumerate(buf)]
    verdict = evaluate(moving, CFG, now_after(moving))
    assert verdict.reason == "over_range" and not verdict.final and verdict.joints_still is False


def test_over_range_before_the_window_does_not_count() -> None:
    buf = series()
    buf[0] = dataclasses.replace(buf[0], over_range=True, length_mm=math.nan)
    assert evaluate(buf, CFG, now_after(buf)).reason is None


# --------------------------------------------------------------------------- moving
def test_moving_joint_is_named_with_its_spread() -> None:
    buf = [with_joint(r, 4, 45.0 + 0.1 * k) for k, r in enumerate(series())]  # 1 deg in window
    verdict = evaluate(buf, CFG, now_after(buf))
    assert verdict.reason == "moving" and verdict.joints_still is False and not verdict.final
    assert verdict.detail.startswith("joint 5 varies by 0.5000 deg")  # max |q - mean|


def test_moving_length_with_still_joints() -> None:
    rng = np.random.default_rng(3)
    buf = [dataclasses.replace(r, length_mm=500.0 + float(rng.normal(0.0, 1.0))) for r in series()]
    verdict = evaluate(buf, CFG, now_after(buf))
    assert verdict.reason == "moving" and verdict.joints_still is True
    assert "cable length varies" in verdict.detail and "settle_tol_mm 0.25" in verdict.detail


def test_motion_before_the_window_does_not_count() -> None:
    buf = series()
    buf[:8] = [with_joint(r, 1, -20.0 + k) for k, r in enumerate(buf[:8])]  # older than 0.5 s
    assert evaluate(buf, CFG, now_after(buf)).reason is None


# --------------------------------------------------------------------------- captures
def test_capture_is_the_window_mean_with_sample_std() -> None:
    rng = np.random.default_rng(11)
    window = [
        dataclasses.replace(
            with_joint(r, 0, float(rng.normal(0.0, 0.01))),
            length_mm=float(rng.normal(700.0, 0.05)),
        )
        for r in series(n=8)
    ]
    cap = make_capture(window, "B", "auto")
    q = np.array([r.joints_deg for r in window])
    lengths = np.array([r.length_mm for r in window])
    assert cap.count == 8 and cap.anchor == "B" and cap.mode == "auto"
    assert cap.length_mm == pytest.approx(lengths.mean(), abs=1e-12)
    assert cap.length_std_mm == pytest.approx(lengths.std(ddof=1), abs=1e-12)
    assert np.allclose(cap.joints_deg, q.mean(axis=0), atol=1e-12)
    assert np.allclose(cap.joints_std_deg, q.std(axis=0, ddof=1), atol=1e-12)
    assert cap.joints_std_deg[1:] == (0.0,) * 5
    assert cap.t_start_wall == window[0].t_wall and cap.t_end_wall == window[-1].t_wall
    assert [(r.t_wall, r.joints_deg, r.length_mm) for r in cap.raw] == [
        (r.t_wall, r.joints_deg, r.length_mm) for r in window
    ]


def test_capture_of_a_single_reading_has_zero_std() -> None:
    cap = make_capture(series(n=1, length_mm=612.5), "A", "manual")
    assert cap.count == 1 and cap.length_mm == 612.5 and cap.length_std_mm == 0.0
    assert cap.joints_deg == HOME and cap.joints_std_deg == (0.0,) * 6


def test_as_joints_takes_six_floats() -> None:
    joints = as_joints(np.arange(6, dtype=np.float64))
    assert joints == (0.0, 1.0, 2.0, 3.0, 4.0, 5.0) and all(type(v) is float for v in joints)
