"""Predicted TCP accuracy (calib.tcp): rigid-motion removal and Monte-Carlo agreement."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calib.cable import N_KIN, ParamLayout, kinematic_parts
from calib.kinematics import forward_position
from calib.models import builtin_model
from calib.synthetic import make_true_cell
from calib.tcp import (
    aligned_position_error_mm,
    remove_rigid,
    tcp_uncertainty,
    tcp_uncertainty_for_problem,
    workspace_sample_deg,
)

MODEL = builtin_model("hsr-jr680")


def test_aligned_error_ignores_a_rigid_motion_and_sees_a_deformation() -> None:
    rng = np.random.default_rng(0)
    pts = rng.uniform(-1000, 1000, size=(50, 3))
    moved = Rotation.from_rotvec([0.1, -0.2, 0.3]).apply(pts) + np.array([5.0, -3.0, 40.0])
    assert aligned_position_error_mm(moved, pts).max() < 1e-9
    bent = moved + rng.normal(0, 0.1, size=pts.shape)
    err = aligned_position_error_mm(bent, pts)
    assert 0.05 < np.sqrt(np.mean(err**2)) < 0.2


def test_remove_rigid_kills_rigid_motions_only() -> None:
    rng = np.random.default_rng(1)
    pts = rng.uniform(-1000, 1000, size=(20, 3))
    rigid = (np.cross([0.0, 0.0, 1e-3], pts) + np.array([0.1, 0.2, 0.3])).reshape(-1, 1)
    assert np.abs(remove_rigid(pts, rigid)).max() < 1e-9
    other = rng.normal(size=(60, 1))
    assert np.linalg.norm(remove_rigid(pts, other)) > 0.5 * np.linalg.norm(other)


def test_base_rotation_and_shift_along_z_are_invisible() -> None:
    """theta1 and d1 move the robot rigidly: any variance on them predicts zero TCP error."""
    layout = ParamLayout(("A",))
    free = np.zeros(layout.size, dtype=bool)
    free[[layout.index("theta1"), layout.index("d1")]] = True
    res = tcp_uncertainty(MODEL, layout, np.zeros(layout.size), free, np.diag([1e-4, 4.0]))
    assert res.max_mm < 1e-9


def test_prediction_matches_monte_carlo_of_aligned_errors() -> None:
    """Draw parameter errors from the covariance, measure the aligned TCP error, compare."""
    cell = make_true_cell(MODEL)
    layout = cell.layout
    names = ("alpha2", "a2", "theta3", "a3", "d4", "alpha5", "tool_x", "p0_x")
    free = np.array([n in names for n in layout.names])
    rng = np.random.default_rng(2)
    half = rng.normal(size=(free.sum(), free.sum())) * 0.02
    cov = half @ half.T + np.diag(np.where(np.array(layout.is_angle)[free], 1e-7, 1e-3))
    q = workspace_sample_deg(MODEL, 200, seed=3)
    pred = tcp_uncertainty(MODEL, layout, cell.theta, free, cov, q_deg=q)
    dh0, tool0 = kinematic_parts(MODEL, cell.theta)
    p_ref = forward_position(dh0, np.deg2rad(q), tool0, MODEL.convention)
    ms = []
    for dx in rng.multivariate_normal(np.zeros(free.sum()), cov, size=200):
        theta = cell.theta.copy()
        theta[free] += dx
        dh, tool = kinematic_parts(MODEL, theta)
        p = forward_position(dh, np.deg2rad(q), tool, MODEL.convention)
        ms.append(np.mean(aligned_position_error_mm(p, p_ref) ** 2))
    measured_rms = float(np.sqrt(np.mean(ms)))
    assert pred.rms_mm > 0.01
    assert measured_rms == pytest.approx(pred.rms_mm, rel=0.1)
    assert pred.max_mm >= pred.rms_mm
    assert set(pred.to_dict()) == {"rms", "max"}
    assert N_KIN == 27


def test_bad_covariance_shape_is_named() -> None:
    layout = ParamLayout(("A",))
    free = np.zeros(layout.size, dtype=bool)
    free[:3] = True
    with pytest.raises(ValueError, match="cov_free"):
        tcp_uncertainty(MODEL, layout, np.zeros(layout.size), free, np.eye(4))


def test_problem_entry_matches_the_layout_entry() -> None:
    """identify's path: a Problem, the free values and their covariance."""
    from calib.problem import Problem
    from calib.synthetic import noisy_lengths, random_poses_deg

    cell = make_true_cell(MODEL)
    rng = np.random.default_rng(4)
    q = random_poses_deg(cell, 40, rng)
    free = np.zeros(cell.layout.size, dtype=bool)
    free[[cell.layout.index(n) for n in ("a2", "alpha3", "tool_z", "p0_y")]] = True
    problem = Problem(
        MODEL,
        cell.layout,
        np.deg2rad(q),
        noisy_lengths(cell, q, rng),
        np.zeros(40, dtype=int),
        free,
        cell.theta,
    )
    cov = np.diag([0.01, 1e-8, 0.02, 0.05])
    a = tcp_uncertainty_for_problem(problem, problem.x0(), cov, n_poses=100, seed=5)
    b = tcp_uncertainty(MODEL, cell.layout, cell.theta, free, cov, n_poses=100, seed=5)
    assert a.rms_mm == pytest.approx(b.rms_mm) and a.max_mm == pytest.approx(b.max_mm)
    assert a.rms_mm > 0.0
