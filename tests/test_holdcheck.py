"""The hold check's decision (the daemon's hold check) as pure functions
(:mod:`calib.monitor.holdcheck`): threshold, judgement, spread and coverage of poses."""

from __future__ import annotations

import math

import numpy as np
import pytest

from calib.monitor.holdcheck import covered, judge, spread_indices, threshold_mm
from daemon.config import HoldCheckSettings


def _threshold(reference_rmse_mm: float | None, s: HoldCheckSettings) -> float:
    return threshold_mm(reference_rmse_mm, s.threshold_mm, s.threshold_factor, s.min_threshold_mm)


def test_threshold_is_three_times_the_calibration_rmse_by_default() -> None:
    s = HoldCheckSettings()
    assert _threshold(0.04, s) == pytest.approx(0.12)
    assert _threshold(0.001, s) == pytest.approx(s.min_threshold_mm)  # the floor
    assert _threshold(0.04, HoldCheckSettings(threshold_factor=5)) == pytest.approx(0.2)
    assert _threshold(0.04, HoldCheckSettings(threshold_mm=0.5)) == 0.5  # absolute wins
    assert _threshold(None, HoldCheckSettings(threshold_mm=0.5)) == 0.5
    assert threshold_mm(0.04, None, 3.0, 0.5) == 0.5  # the floor, from plain numbers
    for ref in (None, math.nan):
        with pytest.raises(ValueError, match=r"hold_check\.threshold_mm"):
            _threshold(ref, s)


def test_judge_flags_only_above_the_threshold() -> None:
    assert judge(0.10, 0.12) == "ok"
    assert judge(0.12, 0.12) == "ok"
    assert judge(0.1201, 0.12) == "not_held"
    assert judge(math.nan, 0.12) == "not_held"


def test_spread_indices_are_distinct_spread_and_deterministic() -> None:
    rng = np.random.default_rng(4)
    q = rng.uniform(-90, 90, size=(200, 6))
    idx = spread_indices(q, 8)
    assert idx == sorted(set(idx)) and len(idx) == 8
    assert idx == spread_indices(q, 8)
    chosen = q[idx]
    d = np.abs(chosen[:, None] - chosen[None]).max(axis=2) + np.eye(8) * 1e9
    random_pick = q[:8]
    d_rand = np.abs(random_pick[:, None] - random_pick[None]).max(axis=2) + np.eye(8) * 1e9
    assert d.min() > d_rand.min()  # farther apart than the first 8 poses
    assert spread_indices(q[:5], 8) == [0, 1, 2, 3, 4]


def test_covered_needs_every_joint_within_tolerance() -> None:
    poses = np.array([[0.0] * 6, [10.0] * 6])
    caps = np.array([[0.3, 0, 0, 0, 0, -0.3], [10.0, 10, 10, 10, 10, 10.6]])
    assert covered(poses, caps, 0.5).tolist() == [True, False]
    assert covered(poses, caps, 0.7).tolist() == [True, True]
    assert covered(poses, np.empty((0, 6)), 0.5).tolist() == [False, False]
