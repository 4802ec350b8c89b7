"""Forward kinematics and the analytic Jacobian, checked against independent computations."""

from __future__ import annotations

import numpy as np
import pytest

from calib.cable import ParamLayout, length_jacobian, multilaterate, predict_lengths
from calib.kinematics import (
    forward_chain,
    forward_position,
    position_jacobian,
    projected_jacobian,
)
from calib.models import RobotModel, builtin_model
from calib.synthetic import make_true_cell, noisy_lengths, random_poses_deg


def _homogeneous_dh(alpha: float, a: float, d: float, theta: float) -> np.ndarray:
    """The paper's eq. (1), written out literally as a 4x4 matrix."""
    ca, sa, ct, st = np.cos(alpha), np.sin(alpha), np.cos(theta), np.sin(theta)
    return np.array(
        [
            [ct, -st * ca, st * sa, a * ct],
            [st, ct * ca, -ct * sa, a * st],
            [0, sa, ca, d],
            [0, 0, 0, 1],
        ]
    )


def _homogeneous_mdh(alpha: float, a: float, d: float, theta: float) -> np.ndarray:
    """Craig: Rx(alpha) Tx(a) Rz(theta) Tz(d), composed from elementary transforms."""
    rx = np.eye(4)
    rx[1:3, 1:3] = [[np.cos(alpha), -np.sin(alpha)], [np.sin(alpha), np.cos(alpha)]]
    tx = np.eye(4)
    tx[0, 3] = a
    rz = np.eye(4)
    rz[0:2, 0:2] = [[np.cos(theta), -np.sin(theta)], [np.sin(theta), np.cos(theta)]]
    tz = np.eye(4)
    tz[2, 3] = d
    return rx @ tx @ rz @ tz


@pytest.mark.parametrize("convention", ["dh", "mdh"])
def test_forward_matches_literal_matrix_product(convention: str) -> None:
    rng = np.random.default_rng(1)
    dh = builtin_model("hsr-jr680").dh_internal() + rng.normal(0, 0.01, (6, 4))
    tool = np.array([12.0, -30.0, 85.0])
    q = rng.uniform(-np.pi, np.pi, (7, 6))
    got = forward_position(dh, q, tool, convention)  # type: ignore[arg-type]
    make = _homogeneous_dh if convention == "dh" else _homogeneous_mdh
    for i in range(q.shape[0]):
        t = np.eye(4)
        for j in range(6):
            t = t @ make(dh[j, 0], dh[j, 1], dh[j, 2], dh[j, 3] + q[i, j])
        np.testing.assert_allclose(got[i], (t @ np.r_[tool, 1.0])[:3], atol=1e-9)


def test_jr680_home_pose_golden() -> None:
    """Golden value: the home pose of Table I (its theta column: the controller reports the DH
    angle itself, the model's offsets are 0), flange centre, computed by hand."""
    model = builtin_model("hsr-jr680")
    assert np.all(model.dh_table[:, 3] == 0.0)
    home_rad = np.deg2rad([[0.0, -90.0, 180.0, 0.0, 90.0, 0.0]])
    pos = forward_position(model.dh_internal(), home_rad, np.zeros(3))
    # Joint 1 puts frame 1 at (a1, 0, d1) = (250, 0, 653.5); θ2 = -90° turns the upper arm
    # (a2 = 900) vertical: (250, 0, 1553.5); θ3 = 180° with a3 = -205 adds 205 upwards:
    # (250, 0, 1758.5); the forearm d4 = 1030.2 points along +x: (1280.2, 0, 1758.5); θ5 = 90°
    # points the flange down, d6 = 200.6: (1280.2, 0, 1557.9).
    np.testing.assert_allclose(pos[0], [1280.2, 0.0, 1557.9], atol=1e-6)


def test_forward_broadcasts_over_parameter_sets() -> None:
    rng = np.random.default_rng(2)
    base = builtin_model("hsr-jr680").dh_internal()
    dhs = base + rng.normal(0, 0.01, (5, 6, 4))
    tools = rng.normal(0, 50, (5, 3))
    q = rng.uniform(-1, 1, (4, 6))
    batch = forward_position(dhs, q, tools)
    assert batch.shape == (5, 4, 3)
    for s in range(5):
        np.testing.assert_allclose(batch[s], forward_position(dhs[s], q, tools[s]), atol=1e-9)


@pytest.mark.parametrize("convention", ["dh", "mdh"])
def test_position_jacobian_matches_finite_differences(convention: str) -> None:
    rng = np.random.default_rng(3)
    dh = builtin_model("hsr-jr680").dh_internal() + rng.normal(0, 0.01, (6, 4))
    tool = np.array([5.0, 40.0, 120.0])
    q = rng.uniform(-np.pi, np.pi, (20, 6))
    _, jac = position_jacobian(dh, q, tool, convention)  # type: ignore[arg-type]
    h = 1e-6
    for k in range(27):
        dp, dm = dh.copy().reshape(-1), dh.copy().reshape(-1)
        tp, tm = tool.copy(), tool.copy()
        if k < 24:
            dp[k] += h
            dm[k] -= h
        else:
            tp[k - 24] += h
            tm[k - 24] -= h
        fd = (
            forward_position(dp.reshape(6, 4), q, tp, convention)  # type: ignore[arg-type]
            - forward_position(dm.reshape(6, 4), q, tm, convention)  # type: ignore[arg-type]
        ) / (2 * h)
        np.testing.assert_allclose(jac[:, :, k], fd, atol=2e-5, err_msg=f"column {k}")


def test_length_jacobian_matches_finite_differences_with_two_anchors() -> None:
    model = builtin_model("hsr-jr680")
    cell = make_true_cell(model, anchor_ids=("A", "B"))
    rng = np.random.default_rng(4)
    q_deg = random_poses_deg(cell, 30, rng)
    idx = rng.integers(0, 2, 30)
    q = np.deg2rad(q_deg)
    _, jac = length_jacobian(model, cell.theta, q, idx)
    h = 1e-6
    for k in range(cell.layout.size):
        tp, tm = cell.theta.copy(), cell.theta.copy()
        tp[k] += h
        tm[k] -= h
        fd = (predict_lengths(model, tp, q, idx) - predict_lengths(model, tm, q, idx)) / (2 * h)
        np.testing.assert_allclose(jac[:, k], fd, atol=2e-5, err_msg=cell.layout.names[k])


@pytest.mark.parametrize("convention", ["dh", "mdh"])
def test_projected_jacobian_equals_direction_times_position_jacobian(convention: str) -> None:
    """The triple-product form used for cable lengths against the frame-based closed form."""
    rng = np.random.default_rng(9)
    dh = builtin_model("hsr-jr680").dh_internal() + rng.normal(0, 0.02, (6, 4))
    tool = np.array([30.0, -20.0, 150.0])
    q = rng.uniform(-np.pi, np.pi, (25, 6))
    direction = rng.normal(size=(25, 3))
    pos, jac = position_jacobian(dh, q, tool, convention)  # type: ignore[arg-type]
    chain = forward_chain(dh, q, tool, convention)  # type: ignore[arg-type]
    np.testing.assert_allclose(chain.pos_mm, pos, atol=1e-9)
    expected = np.einsum("ni,nij->nj", direction, jac)
    np.testing.assert_allclose(projected_jacobian(chain, direction), expected, atol=1e-8)


def test_projected_jacobian_rejects_a_batch_of_parameter_sets() -> None:
    dh = np.broadcast_to(builtin_model("hsr-jr680").dh_internal(), (2, 6, 4))
    chain = forward_chain(dh, np.zeros((3, 6)), np.zeros((2, 3)))
    with pytest.raises(ValueError, match="single parameter set"):
        projected_jacobian(chain, np.ones((3, 3)))


def test_length_jacobian_matches_finite_differences_modified_dh() -> None:
    nominal = builtin_model("hsr-jr680")
    model = RobotModel(
        "mdh-test", "mdh", nominal.dh_table, nominal.joint_limits_deg, np.array([10.0, 5.0, 90.0])
    )
    rng = np.random.default_rng(10)
    layout = ParamLayout(("A",))
    theta = np.zeros(layout.size)
    theta[:27] = rng.normal(0, 0.01, 27)
    theta[27:] = [900.0, 400.0, -300.0, -250.0]
    q = rng.uniform(-2.0, 2.0, (30, 6))
    idx = np.zeros(30, dtype=int)
    _, jac = length_jacobian(model, theta, q, idx)
    h = 1e-6
    for k in range(layout.size):
        tp, tm = theta.copy(), theta.copy()
        tp[k] += h
        tm[k] -= h
        fd = (predict_lengths(model, tp, q, idx) - predict_lengths(model, tm, q, idx)) / (2 * h)
        np.testing.assert_allclose(jac[:, k], fd, atol=2e-5, err_msg=layout.names[k])


def test_multilateration_recovers_anchor_from_clean_lengths() -> None:
    rng = np.random.default_rng(5)
    pts = rng.uniform(-800, 800, (40, 3))
    p0 = np.array([1200.0, -300.0, 150.0])
    lengths = np.linalg.norm(pts - p0, axis=1) - 420.0
    got_p0, got_c = multilaterate(pts, lengths)
    np.testing.assert_allclose(got_p0, p0, atol=1e-6)
    assert got_c == pytest.approx(-420.0, abs=1e-6)


def test_noisy_lengths_are_seeded_and_in_range() -> None:
    cell = make_true_cell(builtin_model("hsr-jr680"))
    q = random_poses_deg(cell, 50, np.random.default_rng(6))
    a = noisy_lengths(cell, q, np.random.default_rng(7))
    b = noisy_lengths(cell, q, np.random.default_rng(7))
    np.testing.assert_array_equal(a, b)
    assert a.min() > 0 and a.max() < 2000


def test_layout_names_and_units() -> None:
    layout = ParamLayout(("A", "B"))
    assert layout.names[:4] == ("alpha1", "a1", "d1", "theta1")
    assert layout.names[24:31] == ("tool_x", "tool_y", "tool_z", "p0_x", "p0_y", "p0_z", "offset")
    assert layout.names[-1] == "offset@B"
    assert layout.units[0] == "deg" and layout.units[1] == "mm"
