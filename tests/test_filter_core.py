"""The filter's core: rotation conventions, frames TOML, every nominal IK solution, the
controller's branch, σ at a tool."""

from __future__ import annotations

import math

import numpy as np
import pytest
from filter_cells import make_cell, regular_poses

from calib.filter.branches import branch_signs, flange_frames, nominal_solutions
from calib.filter.correct import calibration_from_result, sigma_at_tools
from calib.filter.select import choose
from calib.models import builtin_model
from calib.programs.rapid.filter import cfx_of, configuration
from calib.programs.rotations import (
    matrix_to_quat_wxyz,
    matrix_to_rotvec,
    matrix_to_zyx_deg,
    quat_wxyz_to_matrix,
    rotvec_to_matrix,
    zyx_deg_to_matrix,
)
from calib.programs.sites import FilterInputError, parse_frames_toml


def _rz(a: float) -> np.ndarray:
    c, s = math.cos(math.radians(a)), math.sin(math.radians(a))
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def _ry(a: float) -> np.ndarray:
    c, s = math.cos(math.radians(a)), math.sin(math.radians(a))
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rx(a: float) -> np.ndarray:
    c, s = math.cos(math.radians(a)), math.sin(math.radians(a))
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def test_rotation_conventions_exactly() -> None:
    # KUKA A, B, C = Rz(A) Ry(B) Rx(C); Fanuc W, P, R = Rz(R) Ry(P) Rx(W)
    a, b, c = 30.0, -20.0, 110.0
    np.testing.assert_allclose(zyx_deg_to_matrix(a, b, c), _rz(a) @ _ry(b) @ _rx(c), atol=1e-15)
    np.testing.assert_allclose(matrix_to_zyx_deg(_rz(a) @ _ry(b) @ _rx(c)), [a, b, c], atol=1e-9)
    # a whole turn stays near the program's own value
    np.testing.assert_allclose(
        matrix_to_zyx_deg(_rx(-179.0), near_deg=[0, 0, 179.0]), [0, 0, 181.0], atol=1e-9
    )
    # RAPID: w first; 90 deg about z is [cos 45, 0, 0, sin 45]
    np.testing.assert_allclose(
        quat_wxyz_to_matrix(np.array([0.7071068, 0, 0, 0.7071068])), _rz(90.0), atol=1e-7
    )
    q = matrix_to_quat_wxyz(_rz(90.0), near=np.array([-1.0, 0, 0, 0]))
    np.testing.assert_allclose(q, [-math.sqrt(0.5), 0, 0, -math.sqrt(0.5)])  # sign kept
    # UR: rotation vector (axis · angle) in radians
    np.testing.assert_allclose(
        rotvec_to_matrix(np.array([0, math.pi / 2, 0])), _ry(90.0), atol=1e-15
    )
    np.testing.assert_allclose(matrix_to_rotvec(_ry(90.0)), [0, math.pi / 2, 0], atol=1e-15)


def test_frames_toml() -> None:
    f = parse_frames_toml(
        "[uframe.1]\nxyz_mm = [100, 0, 50]\nwpr_deg = [0, 0, 90]\n"
        "[utool.2]\nxyz_mm = [0, 0, 200]\nwpr_deg = [10, 0, 0]\n"
    )
    uf = f.get("uframe", 1)
    assert uf is not None
    np.testing.assert_allclose(uf[:3, :3], _rz(90.0), atol=1e-15)
    ut = f.get("utool", 2)
    assert ut is not None
    np.testing.assert_allclose(ut[:3, :3], _rx(10.0), atol=1e-15)
    np.testing.assert_array_equal(f.get("uframe", 0), np.eye(4))
    assert f.get("utool", 3) is None
    for bad, message in (
        ("[uframe.0]\nxyz_mm=[0,0,0]\nwpr_deg=[0,0,0]", "1..99"),
        ("[base.1]\n", "unknown table"),
        ("[utool.1]\nxyz_mm=[0,0]\nwpr_deg=[0,0,0]", "xyz_mm: expected 3"),
        ("[utool.1\n", "not TOML"),
    ):
        with pytest.raises(FilterInputError, match=message):
            parse_frames_toml(bad)


def test_every_nominal_solution_is_found_and_checked() -> None:
    model = builtin_model("hsr-jr680")
    q = regular_poses(model, 300, seed=9)
    sol = nominal_solutions(model, flange_frames(model, q))
    hit = np.nanmin(np.max(np.abs(sol.joints_deg - q[:, None]), axis=2), axis=1)
    assert np.all(hit < 1e-6)  # the planned joints are among the candidates
    for i in range(20):  # every candidate reaches the same flange pose
        cand = sol.joints_deg[i][sol.valid[i]]
        fk = flange_frames(model, cand)
        np.testing.assert_allclose(
            fk, np.broadcast_to(flange_frames(model, q[i : i + 1]), fk.shape), atol=1e-6
        )
        assert len(cand) >= 2


def test_the_rapid_configuration_picks_the_planned_branch() -> None:
    model = builtin_model("hsr-jr680")
    q = regular_poses(model, 200, seed=10)
    sh, el, wr = branch_signs(model, q)
    confs = []
    for i, qi in enumerate(q):
        cfx = cfx_of(sh[i], el[i], wr[i])
        confs.append(
            configuration(
                [math.floor(qi[0] / 90), math.floor(qi[3] / 90), math.floor(qi[5] / 90), cfx]
            )
        )
    sol = nominal_solutions(model, flange_frames(model, q))
    idx, why = choose(sol, list(confs))
    assert np.all(idx >= 0), why
    np.testing.assert_allclose(sol.joints_deg[np.arange(200), idx], q, atol=1e-6)
    # Another quadrant for joint 6 that no solution has: refused, named.
    far = configuration([math.floor(q[0, 0] / 90), math.floor(q[0, 3] / 90) + 2, 7, 0])
    _, why = choose(nominal_solutions(model, flange_frames(model, q[:1])), [far])
    assert why[0].startswith("no nominal solution in configuration")


def test_sigma_at_a_long_tool_is_larger_than_at_the_flange() -> None:
    cell = make_cell()
    cal = calibration_from_result(cell.result, cell.nominal)
    assert cal.covariance is not None
    q = regular_poses(cell.nominal, 50, seed=3)
    flange = sigma_at_tools(cal, q, np.zeros((50, 3)))
    tool = sigma_at_tools(cal, q, np.tile([0.0, 0.0, 400.0], (50, 1)))
    assert np.all(np.isfinite(tool)) and np.all(tool > 0)
    assert np.sqrt(np.mean(tool**2)) > np.sqrt(np.mean(flange**2))
