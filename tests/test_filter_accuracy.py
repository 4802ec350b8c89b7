"""cablecal filter on an EMULATED truth: the true robot, executing the filtered program
through the nominal controller on the same branch, reaches the intended poses.

**The identification floor** of a target: how far the calibrated model's own prediction of
the tool pose is from the true robot's, at the corrected joints ``q*``
(``|FK_true(q*)·Tool − FK_calibrated(q*)·Tool|``, position [mm] and orientation [deg]). The
filter makes the calibrated model reach the target exactly, so the true robot misses by the
floor plus what the filter adds (IK residual, the written numbers' rounding, a wrong branch
or frame); the tests bound that: ≤ 1.5× the floor + 0.005 mm (+ 0.002° in orientation),
and the RMS ≤ 0.1× the unfiltered program's.
"""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
from filter_cells import (
    Cell,
    make_cell,
    planned_targets,
    rapid_module,
    regular_poses,
    smooth_path,
    tool_frame,
    urscript,
    work_frame,
)

from calib.filter.branches import branch_signs, flange_frames, nominal_solutions
from calib.filter.correct import IK_OPTIONS, calibration_from_result
from calib.filter.run import filter_files
from calib.filter.select import choose
from calib.ik import solve_ik
from calib.kinematics import FloatArray
from calib.programs.rapid.filter import DIALECT as RAPID
from calib.programs.rapid.filter import QUADRANT_EDGE_DEG
from calib.programs.rotations import invert, rotation_angle_deg
from calib.programs.sites import FrameTables, Source, Target
from calib.programs.urscript.filter import DIALECT as URSCRIPT


@pytest.fixture(scope="module")
def cell() -> Cell:
    return make_cell()


def _errors(
    cell: Cell, q: FloatArray, tool: FloatArray, intended: FloatArray, work: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Position [mm] and orientation [deg] errors of the true robot at joints q."""
    reached = invert(work) @ cell.true_flange(q) @ tool
    return (
        np.linalg.norm(reached[:, :3, 3] - intended[:, :3, 3], axis=1),
        rotation_angle_deg(reached[:, :3, :3], intended[:, :3, :3]),
    )


def _floor(cell: Cell, q_star: FloatArray, tool: FloatArray) -> tuple[FloatArray, FloatArray]:
    cal = calibration_from_result(cell.result, cell.nominal).calibrated
    true = cell.true_flange(q_star) @ tool
    model = flange_frames(cal, q_star) @ tool
    return (
        np.linalg.norm(true[:, :3, 3] - model[:, :3, 3], axis=1),
        rotation_angle_deg(true[:, :3, :3], model[:, :3, :3]),
    )


def _check(
    cell: Cell,
    q_plan: FloatArray,
    q_exec: FloatArray,
    q_star: FloatArray,
    tool: FloatArray,
    work: FloatArray,
) -> None:
    intended = planned_targets(cell.nominal, q_plan, tool, work)
    unf_mm, _ = _errors(cell, q_plan, tool, intended, work)
    fil_mm, fil_deg = _errors(cell, q_exec, tool, intended, work)
    floor_mm, floor_deg = _floor(cell, q_star, tool)
    assert np.all(fil_mm <= 1.5 * floor_mm + 0.005), np.max(fil_mm - 1.5 * floor_mm)
    assert np.all(fil_deg <= 1.5 * floor_deg + 0.002), np.max(fil_deg - 1.5 * floor_deg)
    assert rms(fil_mm) <= 0.1 * rms(unf_mm), (rms(fil_mm), rms(unf_mm))
    assert rms(unf_mm) > 1.0  # the cell really is off: the check can fail


def rms(v: FloatArray) -> float:
    return float(np.sqrt(np.mean(v**2)))


def _cartesian(targets: list[Target]) -> list[Target]:
    return [t for t in targets if t.kind == "cartesian"]


@pytest.fixture(scope="module")
def noisy_cell() -> Cell:
    return make_cell(noise_mm=0.05)


@pytest.mark.parametrize(("tool_mm", "noisy"), [(185.0, False), (240.0, False), (220.0, True)])
def test_rapid_program_reaches_the_floor(
    cell: Cell, noisy_cell: Cell, tool_mm: float, noisy: bool
) -> None:
    if noisy:  # lengths with 0.05 mm noise: a real floor, not a noise-free one
        cell = noisy_cell
    nominal = cell.nominal
    q_plan = regular_poses(nominal, 60, seed=int(tool_mm))
    tool, work = tool_frame(tool_mm), work_frame()
    text = rapid_module(nominal, q_plan, tool, work, newline="\r\n")
    run = filter_files(calibration_from_result(cell.result, nominal), [("olp.mod", text.encode())])
    assert [c.status for c in run.corrections] == ["corrected"] * 60
    # The nominal controller executes the filtered file: IK on the written configuration.
    done = _cartesian(
        RAPID.parse([Source.from_bytes("olp.mod", run.outputs["olp.mod"])], FrameTables())
    )
    flanges = np.array(
        [
            t.uses[0].work @ t.pose @ invert(t.uses[0].tool)  # type: ignore[operator, arg-type]
            for t in done
        ]
    )
    sol = nominal_solutions(nominal, flanges)
    idx, why = choose(sol, [t.configuration for t in done])
    assert np.all(idx >= 0), why
    q_exec = sol.joints_deg[np.arange(60), idx]
    q_star = np.array([c.joints_deg for c in run.corrections])
    _check(cell, q_plan, q_exec, q_star, tool, work)
    # The configuration is kept: same branch, a small joint change, quadrants that follow.
    for a, b in zip(branch_signs(nominal, q_plan), branch_signs(nominal, q_exec), strict=True):
        np.testing.assert_array_equal(a, b)
    assert np.max(np.abs(q_exec - q_plan)) < 5.0
    for t, q in zip(done, q_exec, strict=True):
        cf = t.site.conf
        assert [int(n.value) for n in cf[:3]] == [math.floor(q[j] / 90) for j in (0, 3, 5)]
    assert all(c.configuration_kept for c in run.corrections)
    assert all(0 < c.sigma_mm < 1 for c in run.corrections)


def test_polyscope_program_and_its_q_follow_the_correction(cell: Cell) -> None:
    nominal = cell.nominal
    q_plan = regular_poses(nominal, 40, seed=7)
    tool, base = tool_frame(200.0), np.eye(4)
    text = urscript(nominal, q_plan, tool, polyscope=True)
    run = filter_files(calibration_from_result(cell.result, nominal), [("p.script", text.encode())])
    assert {c.status for c in run.corrections} == {"corrected"}
    filtered = Source.from_bytes("p.script", run.outputs["p.script"])
    got = {t.name: t for t in URSCRIPT.parse([filtered], FrameTables())}
    poses = np.array([got[f"Waypoint_{i + 1}_p"].pose for i in range(40)])
    qs = np.array([got[f"Waypoint_{i + 1}_q"].joints_deg for i in range(40)])
    # The UR controller: the IK solution nearest the waypoint's q.
    flanges = poses @ invert(tool)
    sol = solve_ik(nominal, qs, flanges[:, :3, 3], flanges[:, :3, :3], np.zeros(3), IK_OPTIONS)
    assert sol.converged.all()
    # Waypoint_n_q ends as the joints of the corrected pose.
    assert np.max(np.abs(sol.joints_deg - qs)) < 1e-3
    by_name = {t.name: c for t, c in zip(run.targets, run.corrections, strict=True)}
    q_star = np.array([by_name[f"Waypoint_{i + 1}_p"].joints_deg for i in range(40)])
    _check(cell, q_plan, sol.joints_deg, q_star, tool, base)


def test_plain_urscript_path_reaches_the_floor(cell: Cell) -> None:
    nominal = cell.nominal
    q_plan = smooth_path(nominal, 30, seed=4)
    tool = tool_frame(230.0, tilt_deg=10.0)
    text = urscript(nominal, q_plan, tool, polyscope=False)
    run = filter_files(calibration_from_result(cell.result, nominal), [("d.script", text.encode())])
    assert {c.status for c in run.corrections} == {"corrected"}, run.rows()
    targets = URSCRIPT.parse(
        [Source.from_bytes("d.script", run.outputs["d.script"])], FrameTables()
    )
    q_prev = np.asarray(targets[0].joints_deg)  # the movej the script starts with
    q_exec = []
    for t in _cartesian(targets):  # movel: the IK solution nearest the current joints
        fl = (t.pose @ invert(tool))[None]  # type: ignore[operator]
        sol = solve_ik(nominal, q_prev[None], fl[:, :3, 3], fl[:, :3, :3], np.zeros(3), IK_OPTIONS)
        q_prev = sol.joints_deg[0]
        q_exec.append(q_prev)
    corr = [c for t, c in zip(run.targets, run.corrections, strict=True) if t.kind == "cartesian"]
    q_star = np.array([c.joints_deg for c in corr])
    _check(cell, q_plan, np.array(q_exec), q_star, tool, np.eye(4))


def test_a_quadrant_line_crossed_within_the_edge_keeps_the_confdata(cell: Cell) -> None:
    """A correction that moves axis 6 across a 90° line by less than QUADRANT_EDGE_DEG keeps
    the written cf6 (and the target corrected); one that puts it further across than that
    from its written quadrant is left: the confdata would change."""
    nominal = cell.nominal
    q = regular_poses(nominal, 1, seed=21)
    q[0, 5] = 30.0
    tool, work = tool_frame(200.0), work_frame()
    cal = calibration_from_result(cell.result, nominal)
    first = filter_files(cal, [("a.mod", rapid_module(nominal, q, tool, work).encode())])
    delta6 = float(first.corrections[0].joints_deg[5] - q[0, 5])  # type: ignore[index]
    assert 0.001 < abs(delta6) < QUADRANT_EDGE_DEG
    line = 90.0 if delta6 > 0 else 0.0
    q[0, 5] = line - delta6 / 2  # so that q* crosses the line by half the correction
    text = rapid_module(nominal, q, tool, work)
    run = filter_files(cal, [("a.mod", text.encode())])
    assert run.corrections[0].status == "corrected", run.corrections[0].reason
    q6 = float(run.corrections[0].joints_deg[5])  # type: ignore[index]
    assert (q6 - line) * delta6 > 0  # across the line
    (t,) = RAPID.parse([Source.from_bytes("a.mod", run.outputs["a.mod"])], FrameTables())
    (t0,) = RAPID.parse([Source.from_bytes("a.mod", text.encode())], FrameTables())
    assert [n.text for n in t.site.conf] == [n.text for n in t0.site.conf]
    # Written in the quadrant on the far side, axis 6 just inside its edge: q* leaves it.
    q[0, 5] = line + math.copysign(QUADRANT_EDGE_DEG, delta6) - delta6 / 2
    far = rapid_module(nominal, q, tool, work)
    cf6 = math.floor(q[0, 5] / 90.0)
    written = cf6 - 1 if delta6 > 0 else cf6 + 1
    confdata = re.compile(r"\[(-?\d+),(-?\d+),(-?\d+),(\d)\],\[9E")  # the robtarget's
    assert int(confdata.findall(far)[0][2]) == cf6
    far = confdata.sub(lambda m: f"[{m[1]},{m[2]},{written},{m[4]}],[9E", far, count=1)
    left = filter_files(cal, [("a.mod", far.encode())]).corrections[0]
    assert left.status == "skipped"
    assert "would change the configuration" in left.reason and "J6 would be" in left.reason
