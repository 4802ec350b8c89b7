"""ABB ``cfx`` 4..7 (wrist centre behind axis 1) on targets a controller wrote (issue 34 item
3; docs/robots.md, "ABB cfx 4..7"): the pose and confdata numbers of two RobotStudio modules,
checked with the filter's own rule (:func:`calib.programs.rapid.filter.configuration`,
:func:`calib.filter.select.choose`)."""

from __future__ import annotations

import math

import numpy as np

from calib.filter.branches import nominal_solutions
from calib.filter.select import choose
from calib.models import builtin_model
from calib.programs.rapid.filter import cfx_of, configuration
from calib.programs.rotations import frame, quat_wxyz_to_matrix

#: One pose in its eight configurations, as a RobotStudio module writes them (an IRB 140,
#: tool0): position [mm], quaternion, and the confdata of each configuration.
_EIGHT_POSE = (
    [-533.014588406, -47.835810924, 828.73894736],
    [0.635481621, -0.251423899, -0.640712069, 0.349910242],
)
_EIGHT_CONFS = [
    [-2, -2, 0, 1],
    [-2, 0, -2, 0],
    [-2, -2, 0, 3],
    [-2, 0, -2, 2],
    [0, 0, 0, 7],
    [0, -2, -2, 6],
    [0, 0, 0, 5],
    [0, -2, -2, 4],
]


def test_each_of_eight_written_configurations_is_one_solution_of_its_cfx() -> None:
    """Every confdata the controller wrote for one pose (cfx 0..7) selects exactly one
    nominal solution of the IRB 140 under the filter's rule, eight distinct ones, each with
    the written quadrants: the behind-axis-1 (+4) and axis-5 (+1) bits of cfx 4..7."""
    model = builtin_model("abb-irb140")
    pos, quat = _EIGHT_POSE
    fl = frame(np.array(pos), quat_wxyz_to_matrix(np.array(quat)))
    sol = nominal_solutions(model, np.repeat(fl[None], 8, axis=0))
    idx, reasons = choose(sol, [configuration(c) for c in _EIGHT_CONFS])
    assert all(i >= 0 for i in idx), reasons
    picked = np.array([sol.joints_deg[r, i] for r, i in enumerate(idx)])
    assert len({tuple(np.round(q, 3)) for q in picked}) == 8
    for q, c in zip(picked, _EIGHT_CONFS, strict=True):
        assert [math.floor(q[j] / 90.0) for j in (0, 3, 5)] == c[:3]
        assert (c[3] >= 4) == (
            abs(((q[0] - math.degrees(math.atan2(pos[1], pos[0]))) + 180) % 360 - 180) > 90
        )
        assert (c[3] % 2 == 1) == (q[4] < 0)


def test_cfx_4s_lower_arm_bit_behind_axis_1_on_controller_written_targets() -> None:
    """Two RobotStudio-written IRB 120 targets (tool [0,0,205] mm) with cfx 4: each selects
    exactly one nominal solution, behind axis 1. Read with the elbow bit fixed up/down rather
    than the arm's own side, the solution their quadrants leave would be cfx 6, not the 4
    the controller wrote."""
    model = builtin_model("abb-irb120")
    tool = frame(np.array([0.0, 0.0, 205.0]), np.eye(3))
    quat = quat_wxyz_to_matrix(np.array([0.707106781, 0, 0.707106781, 0]))
    written = {
        (156.953224998, -169.221348489, 739.397581873): [0, -1, 0, 4],
        (45.460847582, 225.0, 680.0): [-1, 0, -1, 4],
    }
    fl = np.array([frame(np.array(p), quat) @ np.linalg.inv(tool) for p in written])
    sol = nominal_solutions(model, fl)
    confs = list(written.values())
    idx, reasons = choose(sol, [configuration(c) for c in confs])
    assert all(i >= 0 for i in idx), reasons
    for r, i in enumerate(idx):
        shoulder, elbow, wrist = (int(v[r, i]) for v in (sol.shoulder, sol.elbow, sol.wrist))
        # The written quadrants leave one solution; the filter's cfx of it is the written 4.
        assert shoulder == -1 and cfx_of(shoulder, elbow, wrist) == 4
        fixed_up_down = 4 + (0 if elbow > 0 else 2) + (wrist < 0)
        assert fixed_up_down == 6
