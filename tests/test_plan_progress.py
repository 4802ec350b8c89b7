"""A plan's progress, pure (:mod:`calib.planning.progress`): which planned pose a sample
measured."""

from __future__ import annotations

import numpy as np
import pytest

from calib.planning.progress import match_plan, match_poses


def test_match_poses_tolerance_anchor_and_closest() -> None:
    planned = np.array([[0.0] * 6, [10.0] * 6, [20.0] * 6])
    samples = np.array([[0.4] * 6, [10.0] * 6, [0.1] * 6, [20.0, 20, 20, 20, 20, 20.6]])
    got = match_poses(planned, ["A", "A", "A"], samples, ["A", "B", "A", "A"], tol_deg=0.5)
    # Pose 0: the closer of two matches; pose 1: only a sample at another anchor; pose 2:
    # one joint 0.6 deg off.
    assert got.tolist() == [2, -1, -1]
    assert match_poses(planned, ["A"] * 3, samples, ["A"] * 4, tol_deg=0.7).tolist() == [2, 1, 3]
    assert match_poses(planned, ["A"] * 3, np.zeros((0, 6)), [], 0.5).tolist() == [-1, -1, -1]
    with pytest.raises(ValueError, match="tol_deg"):
        match_poses(planned, ["A"] * 3, samples, ["A"] * 4, tol_deg=0.0)


def test_match_plan_reads_the_stored_pose_rows() -> None:
    poses = [
        {"pose": i, "anchor": a, **{f"q{j}": v for j in range(1, 7)}}
        for i, (a, v) in enumerate((("A", 0.0), ("B", 10.0), ("A", 20.0)))
    ]
    samples = [[10.1] * 6, [0.2] * 6]
    assert match_plan(poses, samples, ["B", "A"]) == [1, 0, -1]
    assert match_plan(poses, [], []) == [-1, -1, -1]
