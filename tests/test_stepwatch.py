"""The live sensor watch's pure decisions (:mod:`calib.monitor.stepwatch`): the step test on
prediction residuals and the robot-or-sensor explanation of a drift check."""

from __future__ import annotations

import numpy as np
import pytest

from calib.monitor.stepwatch import StepDetector, StepSettings, explain_change, next_anchor


def feed(det: StepDetector, residuals: np.ndarray, start: int = 0) -> list[tuple[int, object]]:
    alarms = []
    for i, r in enumerate(residuals, start=start):
        alarm = det.update(i, float(r))
        if alarm is not None:
            alarms.append((i, alarm))
    return alarms


def test_a_step_is_found_after_min_run_samples_and_names_its_first_sample() -> None:
    rng = np.random.default_rng(0)
    det = StepDetector(StepSettings(min_run=3))
    clean = rng.normal(0.0, 0.05, 40)
    assert feed(det, clean) == []
    after = rng.normal(4.0, 0.05, 5)
    alarms = feed(det, after, start=40)
    assert len(alarms) == 1
    at, alarm = alarms[0]
    assert at == 42 and alarm.first_key == 40 and alarm.keys == (40, 41, 42)
    assert alarm.step_mm == pytest.approx(4.0, abs=0.1) and alarm.delay == 3


def test_outliers_and_a_slow_drift_are_not_a_move() -> None:
    rng = np.random.default_rng(1)
    det = StepDetector()
    r = rng.normal(0.0, 0.05, 300) + np.linspace(0.0, 3.0, 300)  # 3 mm over the campaign
    r[[50, 120, 121, 200]] += [6.0, -5.0, 7.0, 9.0]  # single and paired outliers
    assert feed(det, r) == []


def test_a_bump_across_the_cable_scatters_residuals_of_both_signs_and_is_found() -> None:
    rng = np.random.default_rng(2)
    det = StepDetector()
    feed(det, rng.normal(0.0, 0.05, 30))
    signs = np.array([1, -1, 1, 1, -1, -1, 1, -1])
    alarms = feed(det, 2.0 * signs + rng.normal(0.0, 0.05, 8), start=30)
    assert alarms and alarms[0][1].first_key == 30
    assert alarms[0][1].size_mm == pytest.approx(2.0, abs=0.1)


def test_the_band_grows_with_the_residual_scale() -> None:
    det = StepDetector(prior_scale_mm=0.5)  # until 5 clean residuals: the fit's RMSE
    assert det.band_mm == 2.5
    assert feed(det, np.random.default_rng(3).normal(0.0, 0.5, 30)) == []
    assert 1.2 < det.band_mm < 4.0  # five MAD sigmas of 30 residuals of sigma 0.5 mm
    # A 1.5 mm step is within five sigma of noisy residuals: not called a move.
    assert feed(det, np.full(6, 1.5), start=30) == []


def test_settings_and_residuals_are_checked() -> None:
    with pytest.raises(ValueError, match="min_run"):
        StepSettings(min_run=1)
    with pytest.raises(ValueError, match="min_step_mm"):
        StepSettings(min_step_mm=float("nan"))
    with pytest.raises(ValueError, match="sample 7"):
        StepDetector().update(7, float("inf"))


def test_next_anchor_counts_up_and_skips_existing() -> None:
    assert next_anchor("A") == "A2"
    assert next_anchor("A2") == "A3"
    assert next_anchor("A", ["A2", "A3"]) == "A4"
    assert next_anchor("stand9") == "stand10"


def _geometry(n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    u = rng.normal(size=(n, 3)) + np.array([-3.0, 0.0, 0.0])
    u /= np.linalg.norm(u, axis=1)[:, None]
    anchor_jac = np.hstack([-u, np.ones((n, 1))])
    joint_jac = rng.normal(0.0, 10.0, (n, 6))  # mm/deg, pose-dependent
    return anchor_jac, joint_jac


def test_explain_change_tells_a_moved_sensor_from_a_joint_offset() -> None:
    a, j = _geometry(12, 4)
    noise = np.random.default_rng(5).normal(0.0, 0.02, 12)
    sensor = a @ np.array([2.0, -1.0, 0.5, 0.3]) + noise
    out = explain_change(sensor, a, j, noise_mm=0.02)
    assert out["kind"] == "sensor"
    # Along the cable a shift and an offset change look alike: x is the weakest.
    assert out["anchor_shift_mm"] == pytest.approx([2.0, -1.0, 0.5], abs=0.3)
    robot = j[:, 2] * 0.05 + noise
    out = explain_change(robot, a, j, noise_mm=0.02)
    assert out["kind"] == "robot" and out["joint"] == 3
    assert out["joint_offset_deg"] == pytest.approx(0.05, abs=0.005)
    rezero = np.full(12, 0.8) + noise
    assert explain_change(rezero, a, j, noise_mm=0.02)["kind"] == "sensor"
    # Too few poses to tell.
    assert explain_change(sensor[:5], a[:5], j[:5], noise_mm=0.02)["kind"] == "unclear"


def test_a_pose_square_to_the_bump_does_not_end_the_run() -> None:
    det = StepDetector()
    feed(det, np.random.default_rng(6).normal(0.0, 0.05, 20))
    alarms = feed(det, np.array([3.9, 0.3, 3.8, 3.9]), start=20)
    assert [(at, a.first_key, a.keys) for at, a in alarms] == [(23, 20, (20, 21, 22, 23))]
