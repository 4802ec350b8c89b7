"""UR's offset wrist in closed form (calib/filter/ur_ik.py): 8 solutions, FK round trips,
near singularities, near-UR tables (a factory calibration) and the library's UR arms."""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest

from calib.filter.branches import branch_signs, nominal_solutions
from calib.filter.kin import flange_frames
from calib.filter.select import choose
from calib.filter.ur_ik import ORDER, ur_shape, ur_signs, ur_solutions
from calib.kinematics import FloatArray
from calib.models import RobotModel, model_from_mapping
from calib.programs.sites import Configuration

LIBRARY = Path(__file__).resolve().parent.parent / "calib" / "robots" / "library"
ARMS = ("ur3e", "ur5e", "ur10e", "ur16e")


def _arm(name: str) -> RobotModel:
    return model_from_mapping(tomllib.loads((LIBRARY / f"{name}.toml").read_text("utf-8")))


def _wrapped_deg(a: FloatArray) -> FloatArray:
    out: FloatArray = (a + 180.0) % 360.0 - 180.0
    return out


def _random_q(rng: np.random.Generator, n: int, margin_deg: float) -> FloatArray:
    """Joints (n, 6) [deg] at least ``margin_deg`` from the singular values of q3, q5
    (0, ±180)."""
    q = rng.uniform(-180.0, 180.0, size=(n, 6))
    for j in (2, 4):
        s = np.abs(np.sin(np.deg2rad(q[:, j])))
        keep = s > np.sin(np.deg2rad(margin_deg))
        q = q[keep]
    return q


@pytest.mark.parametrize("name", ARMS)
def test_eight_solutions_reproduce_the_pose_and_contain_the_original(name: str) -> None:
    model = _arm(name)
    assert ur_shape(model) is not None and ur_shape(model).exact  # type: ignore[union-attr]
    q = _random_q(np.random.default_rng(3), 600, margin_deg=2.0)
    fl = flange_frames(model, q)
    sol, ok = ur_solutions(model, fl)  # type: ignore[misc]
    # Every candidate reproduces the target to 1e-9 mm (position) and 1e-12 (rotation).
    cand = np.rad2deg(np.where(ok[..., None], sol, 0.0)).reshape(-1, 6)
    back = flange_frames(model, cand).reshape(-1, 8, 4, 4)
    err_mm = np.linalg.norm(back[..., :3, 3] - fl[:, None, :3, 3], axis=2)
    err_rot = np.linalg.norm(back[..., :3, :3] - fl[:, None, :3, :3], axis=(2, 3))
    assert np.max(np.where(ok, err_mm, 0.0)) <= 1e-9
    assert np.max(np.where(ok, err_rot, 0.0)) <= 1e-12
    # The pose's own joints are one of them, on the branch its signs name.
    diff = np.max(np.abs(_wrapped_deg(np.rad2deg(sol) - q[:, None, :])), axis=2)
    hit = np.nanargmin(np.where(ok, diff, np.inf), axis=1)
    assert np.all(diff[np.arange(len(q)), hit] < 1e-7)
    sh, el, wr = ur_signs(model, q)  # type: ignore[misc]
    want = np.array([ORDER.index((s, w, e)) for s, w, e in zip(sh, wr, el, strict=True)])
    assert np.array_equal(hit, want)
    # Far from the singularities the arm reaches its poses 8 ways in most cases.
    assert np.mean(ok.sum(axis=1) == 8) > 0.5


@pytest.mark.parametrize(
    ("joint", "value_deg"),
    [(4, 1e-6), (4, 180.0 - 1e-6), (2, 1e-6), (2, -1e-5)],
    ids=["wrist-q5=0", "wrist-q5=180", "elbow-stretched", "elbow-stretched-neg"],
)
def test_near_singularities_the_original_is_found(joint: int, value_deg: float) -> None:
    model = _arm("ur10e")
    q = _random_q(np.random.default_rng(5), 200, margin_deg=2.0)
    q[:, joint] = value_deg
    fl = flange_frames(model, q)
    sol, ok = ur_solutions(model, fl, ref_table_deg=q)  # type: ignore[misc]
    cand = np.rad2deg(np.where(ok[..., None], sol, 0.0)).reshape(-1, 6)
    back = flange_frames(model, cand).reshape(-1, 8, 4, 4)
    err_mm = np.linalg.norm(back[..., :3, 3] - fl[:, None, :3, 3], axis=2)
    assert np.max(np.where(ok, err_mm, 0.0)) <= 1e-7
    assert np.all(ok.any(axis=1))
    # The nearest candidate is the original pose (to the conditioning of the singularity).
    diff = np.max(np.abs(_wrapped_deg(np.rad2deg(sol) - q[:, None, :])), axis=2)
    assert np.max(np.nanmin(np.where(ok, diff, np.inf), axis=1)) < 1e-3


def test_shoulder_singularity_gives_both_shoulders_as_one() -> None:
    """The wrist point (o5) at exactly D = d4 from axis 1: the two shoulders meet."""
    model = _arm("ur5e")
    q = np.array([[10.0, -60.0, 80.0, -30.0, 50.0, 20.0]])
    fl = flange_frames(model, q)
    d6, d4 = model.dh_table[5, 2], model.dh_table[3, 2]
    o5 = fl[0, :3, 3] - d6 * fl[0, :3, 2]
    radial = np.array([o5[0], o5[1], 0.0]) / np.hypot(o5[0], o5[1])
    fl[0, :3, 3] += radial * (abs(d4) - np.hypot(o5[0], o5[1]))
    sol, ok = ur_solutions(model, fl)  # type: ignore[misc]
    assert ok.sum() >= 2
    cand = np.rad2deg(np.where(ok[..., None], sol, 0.0)).reshape(-1, 6)
    back = flange_frames(model, cand).reshape(-1, 8, 4, 4)
    err_mm = np.linalg.norm(back[..., :3, 3] - fl[:, None, :3, 3], axis=2)
    assert np.max(np.where(ok, err_mm, 0.0)) <= 1e-7
    # Branches 0-3 (shoulder +1) and 4-7 (shoulder -1) share joint 1.
    assert abs(sol[0, 0, 0] - sol[0, 4, 0]) < 1e-7


def test_near_ur_table_is_refined_on_the_model_itself() -> None:
    """A factory-calibrated UR (table off by its deltas) keeps all eight branches."""
    base = _arm("ur10e")
    table = base.dh_table.copy()
    rng = np.random.default_rng(11)
    table[:, 0] += rng.normal(0.0, 0.02, 6)  # alpha [deg]
    table[:, 1] += rng.normal(0.0, 0.3, 6)  # a [mm]
    table[:, 2] += rng.normal(0.0, 0.3, 6)  # d [mm]
    table[:, 3] += rng.normal(0.0, 0.02, 6)  # theta [deg]
    model = RobotModel("ur10e-factory", "dh", table, base.joint_limits_deg)
    shape = ur_shape(model)
    assert shape is not None and not shape.exact
    q = _random_q(rng, 200, margin_deg=5.0)
    fl = flange_frames(model, q)
    sol, ok = ur_solutions(model, fl)  # type: ignore[misc]
    cand = np.rad2deg(np.where(ok[..., None], sol, 0.0)).reshape(-1, 6)
    back = flange_frames(model, cand).reshape(-1, 8, 4, 4)
    err_mm = np.linalg.norm(back[..., :3, 3] - fl[:, None, :3, 3], axis=2)
    assert np.max(np.where(ok, err_mm, 0.0)) <= 1e-6
    diff = np.max(np.abs(_wrapped_deg(np.rad2deg(sol) - q[:, None, :])), axis=2)
    assert np.all(np.nanmin(np.where(ok, diff, np.inf), axis=1) < 1e-5)
    assert np.mean(ok.sum(axis=1) == 8) > 0.5


def test_nominal_solutions_and_nearest_q_pick_the_waypoint_branch() -> None:
    """UR's rule: of all solutions within ±360°, the one nearest the waypoint's q."""
    model = _arm("ur10e")
    q = _random_q(np.random.default_rng(2), 100, margin_deg=5.0)
    q[::2] += 360.0 * np.sign(np.random.default_rng(4).uniform(-1, 1, q[::2].shape))
    q = np.clip(q, -359.0, 359.0)
    sol = nominal_solutions(model, flange_frames(model, q), near_deg=q)
    idx, why = choose(sol, [Configuration(nearest_deg=r) for r in q])
    assert all(not w for w in why)
    got = sol.joints_deg[np.arange(len(q)), idx]
    assert np.max(np.abs(got - q)) < 1e-6
    sh, el, wr = branch_signs(model, q)
    assert np.array_equal(sol.shoulder[np.arange(len(q)), idx], sh)
    assert np.array_equal(sol.elbow[np.arange(len(q)), idx], el)
    assert np.array_equal(sol.wrist[np.arange(len(q)), idx], wr)


def test_not_ur_shaped_is_refused_by_name() -> None:
    base = _arm("ur5e")
    table = base.dh_table.copy()
    table[3, 1] = 40.0  # a4 = 40 mm: neither UR-shaped nor spherical
    model = RobotModel("odd", "dh", table, base.joint_limits_deg)
    assert ur_shape(model) is None
    with pytest.raises(ValueError, match=r"robot odd: .*neither"):
        nominal_solutions(model, flange_frames(model, np.zeros((1, 6))))


def test_a_factory_table_with_far_common_normals_is_solved() -> None:
    """A UR10e's calibrated table as its controller reports it (KinematicsInfo): ``d`` of
    hundreds of metres on the nearly parallel axes 2-4. Values: the real-robot example of
    UniversalRobots/Universal_Robots_ROS2_Driver, ur_calibration/doc/algorithm.rst."""
    theta = [-2.4147806894359e-07, 1.60233952386695, -1.68607190752171, 0.0837331147700119]
    theta += [-1.01260355871158e-07, 3.91986209186124e-08]
    a = [2.12234865571206e-05, 0.0193171326277006, -0.569251663611088, -4.61409023720934e-05]
    a += [-6.39280053471802e-05, 0.0]
    d = [0.180539811714259, 439.140974079901, -446.027059806332, 7.0603368964236]
    d += [0.119811341150314, 0.115670917257426]
    alpha = [1.57014608044242, 0.0013941666682559, 0.00693818880325995, 1.56998468543761]
    alpha += [-1.57038520649543, 0.0]
    table = np.column_stack(
        [np.rad2deg(alpha), 1000.0 * np.array(a), 1000.0 * np.array(d), np.rad2deg(theta)]
    )
    model = RobotModel("ur10e-factory", "dh", table, np.tile([-360.0, 360.0], (6, 1)))
    shape = ur_shape(model)
    assert shape is not None and not shape.exact
    # The neighbour is a UR10e (published a2 = -612.7, a3 = -571.55 mm) to a few tenths of mm.
    assert abs(shape.dh[1, 1] + 612.7) < 1.0 and abs(shape.dh[2, 1] + 571.55) < 1.0
    q = _random_q(np.random.default_rng(6), 300, margin_deg=5.0)
    fl = flange_frames(model, q)
    sol, ok = ur_solutions(model, fl)  # type: ignore[misc]
    cand = np.rad2deg(np.where(ok[..., None], sol, 0.0)).reshape(-1, 6)
    back = flange_frames(model, cand).reshape(-1, 8, 4, 4)
    err_mm = np.linalg.norm(back[..., :3, 3] - fl[:, None, :3, 3], axis=2)
    assert np.max(np.where(ok, err_mm, 0.0)) <= 1e-6
    diff = np.max(np.abs(_wrapped_deg(np.rad2deg(sol) - q[:, None, :])), axis=2)
    found = np.nanmin(np.where(ok, diff, np.inf), axis=1) < 1e-5
    assert found.mean() > 0.97  # the rest: wrist point within ~1 mm of the shoulder cylinder
    # The filter's nearest-q rule still finds every pose's own joints (Newton from q joins).
    sol_n = nominal_solutions(model, fl, near_deg=q)
    idx, _ = choose(sol_n, [Configuration(nearest_deg=r) for r in q])
    assert np.mean(idx >= 0) > 0.97


def test_any_ur_shaped_table_twist_signs_offsets_and_a_tilted_last_frame() -> None:
    """The closed form holds for every table of UR's shape, not only UR's own signs: twists
    -90/-90/+90, joint offsets, d2 and d3, and a last frame with a6 and alpha6."""
    table = np.array(
        [
            [-90.0, 0.0, 150.0, 10.0],
            [0.0, -400.0, 30.0, -20.0],
            [0.0, -350.0, -20.0, 5.0],
            [-90.0, 0.0, 120.0, 30.0],
            [90.0, 0.0, 100.0, -15.0],
            [25.0, 12.0, 90.0, 40.0],
        ]
    )
    model = RobotModel("ur-like", "dh", table, np.tile([-360.0, 360.0], (6, 1)))
    shape = ur_shape(model)
    assert shape is not None and shape.exact
    q = _random_q(np.random.default_rng(9), 400, margin_deg=2.0)
    fl = flange_frames(model, q)
    sol, ok = ur_solutions(model, fl)  # type: ignore[misc]
    diff = np.max(np.abs(_wrapped_deg(np.rad2deg(sol) - q[:, None, :])), axis=2)
    assert np.all(np.nanmin(np.where(ok, diff, np.inf), axis=1) < 1e-7)
