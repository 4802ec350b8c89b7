"""RAPID confdata at a quadrant line and the wrist singularity (issue 34's acceptance: under
a pure shift of the arm, d1 + 0.3 mm, or a pure turn about the base axis, θ1 + 0.05°, every
configuration field stays as written).

The module is written here in the shape RobotStudio stations export (``CONST robtarget
Target_10:=[[x,y,z],[q1..q4],[cf1,cf4,cf6,cfx],[9E+09,…]];``, ``MoveJ``/``MoveL`` with
``tool0\\WObj:=wobj0``); the joints are those the real modules bench/filter_corpus.md names
hold on the line: axis 4 at exactly 0 with a downward tool (rapid-mora), an all-zero wrist with
axis 5 at 90° (rapid-wsierrad-t1 ``Target_270``).
"""

from __future__ import annotations

import re
from dataclasses import replace

import numpy as np
import pytest
from filter_cells import planned_targets, rapid_confdata

from calib.filter.correct import Calibration
from calib.filter.run import filter_files
from calib.filter.select import BRANCH_JUMP_DEG
from calib.kinematics import FloatArray
from calib.models import RobotModel, builtin_model
from calib.programs.rapid.filter import DIALECT as RAPID
from calib.programs.rapid.filter import QUADRANT_EDGE_DEG
from calib.programs.rotations import matrix_to_quat_wxyz
from calib.programs.sites import WRIST_SINGULARITY_REASON, FrameTables, Source
from calib.synthetic import TABLE_XII_D1

NOMINAL = builtin_model("abb-irb120")
#: Joints [deg] on quadrant lines: axis 4 at 0 (mora's), every joint but 5 at 0 (wsierrad's),
#: axis 4 at 0 with axes 1 and 6 equal (mc-example's), and axis 1 just inside the tolerance.
ON_LINES = np.array(
    [
        [18.4802, -6.3963, 19.0527, 0.0, 77.3437, -71.5198],
        [0.0, 0.0, 0.0, 0.0, 90.0, 0.0],
        [3.8141, 27.9532, 40.9295, 0.0, 21.1174, 3.8141],
        [-0.98, 10.0, 20.0, 30.0, 40.0, 50.0],
    ]
)


def _model(d1_mm: float = 0.0, theta1_deg: float = 0.0) -> RobotModel:
    table = NOMINAL.dh_table.copy()
    table[0, 2] += d1_mm
    table[0, 3] += theta1_deg
    return replace(NOMINAL, dh_table=table)


def _module(q: FloatArray) -> str:
    poses = planned_targets(NOMINAL, q, np.eye(4), np.eye(4))
    confs = rapid_confdata(NOMINAL, q)
    if q is ON_LINES:  # axis 1 at -0.98 deg, written in quadrant 0 (inside its edge)
        confs[3] = (0, *confs[3][1:])
    lines = ["MODULE Module1"]
    for i, (p, c) in enumerate(zip(poses, confs, strict=True)):
        xyz = ",".join(f"{v:.3f}" for v in p[:3, 3])
        quat = ",".join(f"{v:.6f}" for v in matrix_to_quat_wxyz(p[:3, :3]))
        conf = ",".join(str(v) for v in c)
        lines.append(
            f"    CONST robtarget Target_{10 * (i + 1)}:=[[{xyz}],[{quat}],[{conf}],"
            "[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]];"
        )
    lines.append("    PROC main()")
    for i in range(len(poses)):
        lines.append(f"        MoveL Target_{10 * (i + 1)},v1000,fine,tool0\\WObj:=wobj0;")
    lines += ["    ENDPROC", "ENDMODULE", ""]
    return "\r\n".join(lines)


def _confs(text: bytes) -> dict[str, str]:
    targets = RAPID.parse([Source.from_bytes("Module1.mod", text)], FrameTables())
    return {t.name: ",".join(n.text for n in t.site.conf) for t in targets}


@pytest.mark.parametrize(("d1_mm", "theta1_deg"), [(0.3, 0.0), (0.0, 0.05)])
def test_a_pure_shift_or_turn_keeps_every_quadrant_on_a_line(
    d1_mm: float, theta1_deg: float
) -> None:
    text = _module(ON_LINES).encode()
    cal = Calibration(NOMINAL, _model(d1_mm, theta1_deg), None, np.zeros(0, dtype=int))
    run = filter_files(cal, [("Module1.mod", text)])
    got = {t.name: c for t, c in zip(run.targets, run.corrections, strict=True)}
    # Target_40 (axis 1 at -0.98) leaves its quadrant under the turn: the next test.
    names = ["Target_10", "Target_20", "Target_30"] + (["Target_40"] if d1_mm else [])
    for name in names:
        assert got[name].status == "corrected", (name, got[name].reason)
    # Every confdata text as written, though axis 4 (or axis 1 under the turn) is now just
    # below its line: -0.0 or -0.05 deg.
    assert _confs(run.outputs["Module1.mod"]) == _confs(text)
    for name in names:
        c = got[name]
        assert c.pose is not None and c.joints_deg is not None
        if d1_mm:
            assert c.shift_mm == pytest.approx(0.3, abs=1e-6)
        else:
            assert c.shift_deg == pytest.approx(0.05, abs=1e-6)
            # The written pose is rounded (3 decimals, 6 in the quaternion): joint 1 to 1e-3 deg.
            q1 = ON_LINES[int(name[7]) - 1, 0] - 0.05
            assert float(c.joints_deg[0]) == pytest.approx(q1, abs=1e-3)
    # Target_20's axis 1 crossed the line by the turn: kept in its quadrant.
    if theta1_deg:
        assert float(got["Target_20"].joints_deg[0]) < 0.0  # type: ignore[index]


def test_a_joint_further_across_the_line_than_the_tolerance_is_left_named() -> None:
    """Target_40 has axis 1 at -0.98 deg written in quadrant 0: a turn of 0.05 deg puts it at
    -1.03, beyond QUADRANT_EDGE_DEG: the confdata would change, so the target is left."""
    assert -1.03 < -QUADRANT_EDGE_DEG <= -0.98  # the test's numbers are placed for it
    text = _module(ON_LINES).encode()
    cal = Calibration(NOMINAL, _model(theta1_deg=0.05), None, np.zeros(0, dtype=int))
    run = filter_files(cal, [("Module1.mod", text)])
    got = {t.name: c for t, c in zip(run.targets, run.corrections, strict=True)}
    assert got["Target_40"].status == "skipped"
    assert "would change the configuration [0,0,0,0]" in got["Target_40"].reason
    assert "J1 would be -1.030 deg" in got["Target_40"].reason
    same = Calibration(NOMINAL, NOMINAL, None, np.zeros(0, dtype=int))
    assert filter_files(same, [("Module1.mod", text)]).outputs["Module1.mod"] == text


def test_a_target_at_the_wrist_singularity_is_left_named() -> None:
    """A jointtarget at the IRB 120's home (every joint 0, so J5 = 0: axes 4 and 6 in line)
    and a robtarget there with J5 = 0.2 deg (a pose written at J5 = 0 rounds to either wrist
    sign), as RobotStudio stations write them, under a realistic calibration (each
    DH entry + N(0, |Table XII D1|), the corpus's seed): the calibrated solution turns J4 and
    J6 by tens of degrees, so both are left as the wrist singularity, with J5 and the turn;
    a target with J5 = 40 deg beside them is corrected."""
    rng = np.random.default_rng(34)
    table = NOMINAL.dh_table + rng.normal(0.0, 1.0, (6, 4)) * np.abs(TABLE_XII_D1)
    cal = Calibration(NOMINAL, replace(NOMINAL, dh_table=table), None, np.zeros(0, dtype=int))
    q = np.array([[0.0, 0.0, 0.0, 0.0, 0.2, 0.0], [10.0, 20.0, 10.0, 30.0, 40.0, 50.0]])
    text = _module(q).replace(
        "    PROC main()",
        "    CONST jointtarget jHome:=[[0,0,0,0,0,0],[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]];\r\n"
        "    PROC main()\r\n        MoveAbsJ jHome,v1000,fine,tool0;",
    )
    run = filter_files(cal, [("Module1.mod", text.encode())])
    got = {t.name: c for t, c in zip(run.targets, run.corrections, strict=True)}
    assert got["Target_20"].status == "corrected", got["Target_20"].reason
    for name in ("Target_10", "jHome"):
        assert got[name].status == "skipped"
        reason = got[name].reason
        assert reason.startswith(f"{WRIST_SINGULARITY_REASON} (J5 = "), reason
        turned = [
            float(v)
            for v in re.findall(r"turns J4 by (-?[\d.]+) deg and J6 by (-?[\d.]+)", reason)[0]
        ]
        assert abs(turned[0]) > BRANCH_JUMP_DEG and turned[0] * turned[1] < 0
