"""Compensation: corrected joints on the calibrated model reach the nominal targets."""

from __future__ import annotations

import csv
import io
import json
from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calib.compensate import (
    CartesianTargets,
    CompensateOptions,
    JointTargets,
    compensate,
    parse_targets_csv,
)
from calib.dataset import make_samples
from calib.export import model_from_result
from calib.filter.select import branch_of, left_branch, wrist_flipped
from calib.identify import IdentifyOptions, identify
from calib.ik import IKOptions, _errors_and_jacobian, tool_pose, wrist_bend
from calib.kinematics import FloatArray, forward_position
from calib.models import BUILTIN_MODELS, RobotModel, builtin_model
from calib.synthetic import TABLE_XII_D1, TrueCell, make_true_cell, noisy_lengths, random_poses_deg
from calib.verify import aligned_rms_mm

NOISE_MM = 0.05
FLANGE = np.zeros(3)


@pytest.fixture(scope="module")
def nominal() -> RobotModel:
    return builtin_model("hsr-jr680")


@pytest.fixture(scope="module")
def calibrated_cell(nominal: RobotModel) -> tuple[TrueCell, RobotModel]:
    """A true cell without joint-6 errors, and the model identified from 100 noisy poses."""
    errors = TABLE_XII_D1.copy()
    errors[5] = 0.0
    cell = make_true_cell(nominal, dh_errors_deg_mm=errors)
    rng = np.random.default_rng(11)
    q = random_poses_deg(cell, 100, rng)
    samples = make_samples(q, noisy_lengths(cell, q, rng, noise_mm=NOISE_MM))
    result = identify(nominal, samples, IdentifyOptions(test_fraction=0.0))
    return cell, model_from_result(result.to_json(), nominal)


def _true_flange(cell: TrueCell, q_deg: FloatArray) -> FloatArray:
    dh = cell.model.dh_internal() + cell.theta[:24].reshape(6, 4)
    return forward_position(dh, np.deg2rad(q_deg), FLANGE, cell.model.convention)


def _regular_poses(model: RobotModel, n: int, seed: int) -> FloatArray:
    """Random poses away from singularities: condition number of the pose Jacobian (rotation
    rows × 1000 mm/rad) below 25 (the JR680 has elbow singularities at q3 ≈ 101 and 281 deg)."""
    rng = np.random.default_rng(seed)
    out = np.empty((0, 6))
    tool = np.array([10.0, -20.0, 150.0])
    while out.shape[0] < n:
        q = rng.uniform(
            [-150, -120, 70, -150, -110, -150], [150, 60, 290, 150, 110, 150], size=(4 * n, 6)
        )
        eye = np.tile(np.eye(3), (q.shape[0], 1, 1))
        _, _, jac = _errors_and_jacobian(
            model, model.dh_internal(), np.deg2rad(q), tool, np.zeros((q.shape[0], 3)), eye
        )
        jac[:, 3:] *= 1000.0
        sv = np.linalg.svd(jac, compute_uv=False)
        out = np.vstack([out, q[sv[:, 0] < 25 * sv[:, -1]]])
    return out[:n]


def test_acceptance_true_robot_reaches_nominal_flange_targets(
    nominal: RobotModel, calibrated_cell: tuple[TrueCell, RobotModel]
) -> None:
    cell, calibrated = calibrated_cell
    q_targets = random_poses_deg(cell, 200, np.random.default_rng(12))
    targets_mm = forward_position(nominal.dh_internal(), np.deg2rad(q_targets), FLANGE)
    out = compensate(nominal, calibrated, JointTargets(q_targets))
    assert np.all(out.position_residual_mm < 1e-5)
    uncompensated = aligned_rms_mm(_true_flange(cell, q_targets), targets_mm)
    compensated = aligned_rms_mm(_true_flange(cell, out.corrected_joints_deg), targets_mm)
    own = aligned_rms_mm(
        forward_position(calibrated.dh_internal(), np.deg2rad(q_targets), FLANGE),
        _true_flange(cell, q_targets),
    )
    print(
        f"aligned RMS: uncompensated {uncompensated:.4f} mm, compensated {compensated:.4f} mm, "
        f"identification's own {own:.4f} mm; flagged {out.summary['flag_counts']}"
    )
    assert uncompensated > 1.0  # Table XII errors: millimetres before compensation
    assert compensated <= 0.2 * uncompensated
    assert compensated <= 1.5 * own


def test_identical_models_leave_the_joints_unchanged(nominal: RobotModel) -> None:
    q = _regular_poses(nominal, 50, 1)
    for mode in ("position", "pose"):
        out = compensate(nominal, nominal, JointTargets(q), CompensateOptions(mode=mode))
        np.testing.assert_allclose(out.corrected_joints_deg, q, atol=1e-12)
        assert np.all(out.iterations == 0)
        assert out.ok.all()
        np.testing.assert_allclose(out.uncompensated_error_mm, 0.0, atol=1e-9)


def test_pose_mode_matches_position_and_orientation(
    nominal: RobotModel, calibrated_cell: tuple[TrueCell, RobotModel]
) -> None:
    _, calibrated = calibrated_cell
    q = _regular_poses(nominal, 300, 2)
    tool = (10.0, -20.0, 150.0)
    out = compensate(nominal, calibrated, JointTargets(q), CompensateOptions("pose", tool))
    assert out.ok.all(), out.summary
    pos_t, rot_t = tool_pose(nominal, q, np.array(tool))
    pos_c, rot_c = tool_pose(calibrated, out.corrected_joints_deg, np.array(tool))
    np.testing.assert_allclose(pos_c, pos_t, atol=1e-5)
    angle = Rotation.from_matrix(rot_t @ np.swapaxes(rot_c, 1, 2)).magnitude()
    assert np.rad2deg(angle).max() < 1e-5
    assert np.nanmax(out.rotation_residual_deg) < 1e-5
    assert out.iterations.max() <= 10  # Newton-like from the nominal joints
    assert np.all(out.uncompensated_error_mm > 0.1)


def test_cartesian_targets_give_the_same_corrections_as_joint_targets(
    nominal: RobotModel, calibrated_cell: tuple[TrueCell, RobotModel]
) -> None:
    _, calibrated = calibrated_cell
    q = _regular_poses(nominal, 100, 3)
    pos, rot = tool_pose(nominal, q, FLANGE)
    rpy = Rotation.from_matrix(rot).as_euler("xyz", degrees=True)
    seed = q + np.random.default_rng(4).uniform(-3, 3, size=q.shape)
    opts = CompensateOptions(mode="pose")
    cart = compensate(nominal, calibrated, CartesianTargets(pos, rpy, seed), opts)
    joint = compensate(nominal, calibrated, JointTargets(q), opts)
    assert cart.ok.all(), cart.summary
    np.testing.assert_allclose(cart.nominal_joints_deg, q, atol=1e-6)
    np.testing.assert_allclose(cart.corrected_joints_deg, joint.corrected_joints_deg, atol=1e-6)
    assert np.all(cart.iterations > joint.iterations)  # the nominal stage counts too
    # The corrected Cartesian target is the nominal pose at the corrected joints.
    back = tool_pose(nominal, cart.corrected_joints_deg, FLANGE)[0]
    np.testing.assert_allclose(cart.corrected_position_mm, back, atol=1e-9)


def test_position_mode_cartesian_from_one_home_seed(nominal: RobotModel) -> None:
    q = _regular_poses(nominal, 40, 5)
    q[:, 0] = np.clip(q[:, 0], -60, 60)
    pos = tool_pose(nominal, q, FLANGE)[0]
    home = np.array([0.0, -30.0, 180.0, 0.0, 45.0, 0.0])
    out = compensate(nominal, nominal, CartesianTargets(pos, None, home))
    assert not any("nominal_ik_failed" in f for f in out.flags)
    np.testing.assert_allclose(
        tool_pose(nominal, out.corrected_joints_deg, FLANGE)[0], pos, atol=1e-5
    )


def test_geometric_jacobian_matches_finite_differences(nominal: RobotModel) -> None:
    mdh = replace(nominal, convention="mdh")
    q = np.deg2rad(_regular_poses(nominal, 5, 6))
    tool = np.array([30.0, 40.0, 120.0])
    for model in (nominal, mdh):
        dh = model.dh_internal()
        target_rot = np.tile(np.eye(3), (5, 1, 1))
        e_pos, _, jac = _errors_and_jacobian(model, dh, q, tool, np.zeros((5, 3)), target_rot)
        h = 1e-7
        for j in range(6):
            dq = np.zeros(6)
            dq[j] = h
            e2, _, _ = _errors_and_jacobian(model, dh, q + dq, tool, np.zeros((5, 3)), target_rot)
            np.testing.assert_allclose(-(e2 - e_pos) / h, jac[:, :3, j], atol=1e-4)


def _theta_shift(model: RobotModel, joint: int, dtheta_deg: float) -> RobotModel:
    table = model.dh_table.copy()
    table[joint - 1, 3] += dtheta_deg
    return replace(model, dh_table=table)


def test_flags_branch_jump_limits_and_failures(nominal: RobotModel) -> None:
    q = _regular_poses(nominal, 20, 7)
    shifted = _theta_shift(nominal, 2, 8.0)
    out = compensate(nominal, shifted, JointTargets(q), CompensateOptions(mode="pose"))
    assert all("branch_jump" in f for f in out.flags)
    np.testing.assert_allclose(out.corrected_joints_deg[:, 1] - q[:, 1], -8.0, atol=1e-6)

    at_limit = q.copy()
    at_limit[:, 1] = 90.0  # the JR680's q2 upper limit
    nudged = _theta_shift(nominal, 2, -0.5)
    out = compensate(nominal, nudged, JointTargets(at_limit), CompensateOptions(mode="pose"))
    assert all(any(x.startswith("outside_limits:J") for x in f) for f in out.flags)
    assert not out.ok.any()

    far = CartesianTargets(np.array([[5000.0, 0.0, 0.0]]), None, q[0])
    out = compensate(nominal, nominal, far, CompensateOptions(ik=IKOptions(max_iterations=30)))
    assert out.flags[0][:1] == ["nominal_ik_failed"] and "ik_failed" in out.flags[0]
    assert out.position_residual_mm[0] > 1000


def test_wrist_flip_changes_the_bend_sign(nominal: RobotModel) -> None:
    q = _regular_poses(nominal, 10, 8)
    flipped = q + np.array([0, 0, 0, 180.0, 0, 180.0])
    flipped[:, 4] = -q[:, 4] - 2 * nominal.dh_table[4, 3]  # mirror about the DH offset (90°)
    p1, r1 = tool_pose(nominal, q, FLANGE)
    p2, r2 = tool_pose(nominal, flipped, FLANGE)
    np.testing.assert_allclose(p2, p1, atol=1e-8)
    np.testing.assert_allclose(r2, r1, atol=1e-12)
    assert np.all(np.sign(wrist_bend(nominal, q)) != np.sign(wrist_bend(nominal, flipped)))
    far = np.abs(q[:, 4]) >= 1.0
    np.testing.assert_array_equal(wrist_flipped(q, flipped, 1.0), far)
    assert not wrist_flipped(q, q + 0.5, 1.0).any()
    assert np.all(left_branch(nominal, q[far], flipped[far], wrist_floor_deg=1.0))


def test_the_engines_wrist_sign_is_the_geometric_bend_on_every_builtin_arm() -> None:
    """The correction engine's wrist (the sign of the controller's joint 5, as the programs'
    configurations count it) is the sign of ``(z4 × z6) · z5`` on every built-in arm, so
    compensate's wrist flip is the geometric one it always was."""
    rng = np.random.default_rng(3)
    for name in sorted(BUILTIN_MODELS):
        model = builtin_model(name)
        q = rng.uniform(-170, 170, size=(200, 6))
        q = q[np.abs(q[:, 4]) > 0.5]
        bend = np.sign(wrist_bend(model, q)).astype(int)
        np.testing.assert_array_equal(branch_of(model, q)[:, 2], bend, err_msg=name)


def test_outputs_csv_and_json(nominal: RobotModel) -> None:
    q = _regular_poses(nominal, 5, 9)
    bent = replace(nominal, dh_table=nominal.dh_table + 0.01)
    out = compensate(nominal, bent, JointTargets(q))
    rows = list(csv.DictReader(io.StringIO(out.to_csv())))
    assert len(rows) == 5
    # 0.001 deg in the CSV, no 17-digit floats
    np.testing.assert_allclose(
        [[float(r[f"q{j + 1}"]) for j in range(6)] for r in rows],
        out.corrected_joints_deg,
        atol=5e-4 + 1e-9,
    )
    assert all(len(r["q1"].split(".")[1]) == 3 for r in rows)
    doc = json.loads(json.dumps(out.to_json()))  # NaN orientation residuals become null
    assert doc["rows"][0]["residual_deg"] is None
    assert "base z axis" in doc["note"] and "joint-6" in doc["note"]
    assert "Pose mode" not in doc["note"]
    pose = compensate(nominal, bent, JointTargets(q), CompensateOptions(mode="pose"))
    assert "Pose mode" in pose.note
    assert doc["summary"]["n"] == 5


def test_bad_input_is_named(nominal: RobotModel) -> None:
    with pytest.raises(ValueError, match="joints_deg"):
        compensate(nominal, nominal, JointTargets(np.zeros((3, 5))))
    with pytest.raises(ValueError, match="rotation_deg"):
        compensate(
            nominal,
            nominal,
            CartesianTargets(np.zeros((2, 3)), None, np.zeros(6)),
            CompensateOptions(mode="pose"),
        )
    with pytest.raises(ValueError, match="seed_deg"):
        compensate(nominal, nominal, CartesianTargets(np.zeros((2, 3)), None, np.zeros(5)))
    with pytest.raises(ValueError, match="mode"):
        CompensateOptions(mode="joints")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="tol_mm"):
        IKOptions(tol_mm=0.0)
    with pytest.raises(ValueError, match="line 3, column 'q4'"):
        parse_targets_csv("q1,q2,q3,q4,q5,q6\n0,0,90,0,0,0\n0,0,90,x,0,0\n")
    with pytest.raises(ValueError, match="seed_deg"):
        parse_targets_csv("x,y,z\n1,2,3\n")
    with pytest.raises(ValueError, match="line 1"):
        parse_targets_csv("a,b\n1,2\n")


def test_parse_targets_csv(nominal: RobotModel) -> None:
    joints = parse_targets_csv("Q1,q2,q3,q4,q5,q6,comment\n1,2,90,4,5,6,x\n\n")
    assert isinstance(joints, JointTargets) and joints.joints_deg.shape == (1, 6)
    cart = parse_targets_csv("x,y,z,rx,ry,rz\n1000,0,1500,180,0,0\n", seed_deg=np.zeros(6))
    assert isinstance(cart, CartesianTargets)
    assert cart.rotation_deg is not None and cart.rotation_deg[0, 0] == 180.0


def test_joint_weights_shift_the_correction_to_cheap_joints(nominal: RobotModel) -> None:
    q = _regular_poses(nominal, 30, 10)
    bent = replace(nominal, dh_table=nominal.dh_table + [[0.0, 0.5, 0.3, 0.05]] * 6)
    plain = compensate(nominal, bent, JointTargets(q))
    heavy = compensate(
        nominal,
        bent,
        JointTargets(q),
        CompensateOptions(ik=IKOptions(joint_weights=(100.0, 1.0, 1.0, 1.0, 1.0, 1.0))),
    )
    np.testing.assert_allclose(heavy.position_residual_mm, 0.0, atol=1e-6)
    moved_plain = np.abs(plain.corrected_joints_deg[:, 0] - q[:, 0])
    moved_heavy = np.abs(heavy.corrected_joints_deg[:, 0] - q[:, 0])
    assert moved_heavy.mean() < 0.5 * moved_plain.mean()
    with pytest.raises(ValueError, match="joint_weights"):
        IKOptions(joint_weights=(1.0, 1.0, 1.0, 1.0, 1.0, 0.0))


def test_stalled_targets_stop_early_with_their_best_joints(nominal: RobotModel) -> None:
    from calib.ik import solve_ik

    seed = _regular_poses(nominal, 3, 12)
    far = np.array([[5000.0, 0.0, 500.0], [0.0, -5000.0, 0.0], [3000.0, 3000.0, 3000.0]])
    start = np.linalg.norm(tool_pose(nominal, seed, FLANGE)[0] - far, axis=1)
    sol = solve_ik(nominal, seed, far, None, FLANGE, IKOptions(max_iterations=500))
    assert not sol.converged.any()
    assert np.all(sol.iterations < 500)  # given up by the stall test, not the iteration cap
    reach = np.linalg.norm(tool_pose(nominal, sol.joints_deg, FLANGE)[0] - far, axis=1)
    np.testing.assert_allclose(sol.position_error_mm, reach)
    assert np.all(reach < start - 1000.0)  # it stretched toward the target first
    with pytest.raises(ValueError, match="stall_iterations"):
        IKOptions(stall_iterations=0)


def test_rotation_vector_matches_scipy() -> None:
    from calib.ik import rotation_vector

    rng = np.random.default_rng(13)
    vecs = rng.normal(size=(200, 3))
    vecs *= (rng.uniform(0, np.pi, size=200) / np.linalg.norm(vecs, axis=1))[:, None]
    vecs[:3] = [[0, 0, 0], [1e-9, 0, 0], [0, np.pi - 1e-6, 0]]
    mats = Rotation.from_rotvec(vecs).as_matrix()
    np.testing.assert_allclose(rotation_vector(mats), vecs, atol=1e-9)
