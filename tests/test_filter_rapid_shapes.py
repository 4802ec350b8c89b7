"""The RAPID dialect on the shapes real modules have (issue 34): routine scope, inline literals
of any type, PERS / TASK PERS / LOCAL / arrays, tools across modules, ``ConfL\\Off`` followed
along the flow, external axes, modules cut short, absurd numbers.

The fixtures are written here in the shapes of RobotStudio and OLP modules (docs/compensation.md
names the public modules the shapes come from); targets are planned on the nominal model.
"""

from __future__ import annotations

import math
import re
from dataclasses import replace

import numpy as np
import pytest
from filter_cells import planned_targets, rapid_confdata, regular_poses, smooth_path, tool_frame

from calib.filter.branches import branch_signs
from calib.filter.correct import Calibration
from calib.filter.run import EXIT_BAD_INPUT, EXIT_OK, FilterRun, filter_files
from calib.kinematics import FloatArray
from calib.models import RobotModel, builtin_model
from calib.programs.common import ProgramError
from calib.programs.rapid.filter import DIALECT as RAPID
from calib.programs.rapid.filter import cfx_of, configuration
from calib.programs.rapid.program import parse as parse_program
from calib.programs.rotations import matrix_to_quat_wxyz
from calib.programs.sites import EXTERNAL_AXIS_REASON, FrameTables, Source, Target

NOMINAL = builtin_model("hsr-jr680")
NO_AXES = "[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]"
NUMBER = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")


def _calibrated(nominal: RobotModel) -> RobotModel:
    """The nominal model with small DH errors (mm, deg) on every joint but the sixth."""
    delta = np.zeros((6, 4))
    delta[0, 2], delta[1, 1], delta[1, 3], delta[2, 0] = 0.2, 0.3, 0.05, 0.02
    delta[2, 1], delta[3, 2], delta[4, 3] = -0.2, 0.25, -0.04
    return replace(nominal, dh_table=nominal.dh_table + delta)


CAL = Calibration(NOMINAL, _calibrated(NOMINAL), None, np.zeros(0, dtype=int))
SAME = Calibration(NOMINAL, NOMINAL, None, np.zeros(0, dtype=int))
TOOL = tool_frame(180.0)
TOOL_TEXT = "[TRUE,[[8,-5,180],[1,0,0,0]],[2.5,[0,0,60],[1,0,0,0],0,0,0]]"


def _tool() -> FloatArray:
    out = np.eye(4)
    out[:3, 3] = [8.0, -5.0, 180.0]
    return out


def _robtarget(pose: FloatArray, conf: tuple[int, ...], eax: str = NO_AXES) -> str:
    p = ",".join(f"{v:.3f}" for v in pose[:3, 3])
    q = ",".join(f"{v:.6f}" for v in matrix_to_quat_wxyz(pose[:3, :3]))
    return f"[[{p}],[{q}],[{','.join(str(c) for c in conf)}],{eax}]"


def _targets(q: FloatArray, work: FloatArray | None = None) -> tuple[list[str], FloatArray]:
    """Robtarget literals of joints (n, 6) [deg] with their confdata, in ``work`` (default
    wobj0) of the tool."""
    poses = planned_targets(NOMINAL, q, _tool(), np.eye(4) if work is None else work)
    confs = rapid_confdata(NOMINAL, q)
    return [_robtarget(p, c) for p, c in zip(poses, confs, strict=True)], poses


def _run(cal: Calibration, **files: str) -> FilterRun:
    return filter_files(cal, [(n.replace("_", "."), t.encode()) for n, t in files.items()])


def _by_name(run: FilterRun) -> dict[str, tuple[Target, str, str]]:
    return {
        t.name: (t, c.status, c.reason) for t, c in zip(run.targets, run.corrections, strict=True)
    }


def _masked(text: str) -> str:
    return NUMBER.sub("#", text)


# -- the shapes ---------------------------------------------------------------------------
def _shapes_module() -> str:
    """Every declaration shape and inline literal in one module (RobotStudio's layout)."""
    lits, _ = _targets(regular_poses(NOMINAL, 9, seed=21))
    return "\n".join(
        [
            "%%%",
            "  VERSION:1",
            "  LANGUAGE:ENGLISH",
            "%%%",
            "MODULE Shapes",
            f"    PERS tooldata tGrip:={TOOL_TEXT};",
            f"    CONST robtarget pA:={lits[0]};  ! module level, shadowed below",
            f"    PERS robtarget pPers:={lits[1]};",
            f"    TASK PERS robtarget pTask:={lits[2]};",
            f"    LOCAL CONST robtarget pLocal:={lits[3]};",
            f"    CONST robtarget pArr{{2}}:=[{lits[4]},\r\n        {lits[5]}];",
            "    CONST jointtarget jHome:=[[0,-20,160,0,40,0],[9E9,9E9,9E9,9E9,9E9,9E9]];",
            "    PROC Path_10()",
            f"        VAR robtarget pA:={lits[6]};",
            "        MoveAbsJ jHome\\NoEOffs, [1000,200,5000,1000], fine, tool0;",
            "        MoveL pA, v200, [FALSE,5,8,8,0.8,8,0.8], tGrip;",
            "        MoveJ pPers, v200, z10, tGrip\\WObj:=wobj0;",
            "        MoveL pTask, v200, z10, tGrip;",
            "    ENDPROC",
            "    LOCAL PROC Path_20()",
            f"        VAR robtarget pA:={lits[7]};",
            "        MoveL pA, v200, fine, tGrip;",
            "        MoveL pLocal, v200, fine, tGrip;",
            "        MoveL pArr{2}, v200, fine, tGrip;",
            f"        MoveL {lits[8]}, v200, fine, tGrip;",
            "    ENDPROC",
            "ENDMODULE",
            "",
        ]
    )


def test_every_shape_is_read_and_corrected_in_place() -> None:
    text = _shapes_module()
    run = _run(CAL, shapes_mod=text)
    assert not run.errors
    got = _by_name(run)
    assert set(got) == {
        "pA",
        "pPers",
        "pTask",
        "pLocal",
        "pArr{1}",
        "pArr{2}",
        "jHome",
        "Path_10/pA",
        "Path_20/pA",
        "inline@26",
    }
    # Routine scope: each routine's pA is its own target; the module's pA is shadowed.
    assert [u.line for u in got["Path_10/pA"][0].uses] == [17]
    assert [u.line for u in got["Path_20/pA"][0].uses] == [23]
    assert got["pA"][1:] == ("skipped", got["pA"][2]) and "not used" in got["pA"][2]
    assert got["pArr{1}"][1] == "skipped"  # declared, never moved to
    for name in ("pPers", "pTask", "pLocal", "pArr{2}", "jHome", "Path_10/pA", "Path_20/pA"):
        assert got[name][1] == "corrected", (name, got[name][2])
    assert got["inline@26"][1] == "corrected"
    out = run.outputs["shapes.mod"].decode()
    assert out != text and _masked(out) == _masked(text)  # only numbers changed
    line = out.splitlines()[25]
    assert line != text.splitlines()[25] and line.rstrip().endswith("v200, fine, tGrip;")


def test_the_nominal_model_changes_no_byte() -> None:
    text = _shapes_module()
    run = _run(SAME, shapes_mod=text)
    assert not run.errors
    assert run.outputs["shapes.mod"] == text.encode()


def test_tools_and_work_objects_across_modules() -> None:
    table = np.eye(4)
    table[:3, 3] = [900.0, -250.0, 300.0]
    lits, _ = _targets(regular_poses(NOMINAL, 2, seed=5), table)
    main = (
        "MODULE MainModule\n"
        f"    CONST robtarget p1:={lits[0]};\n    CONST robtarget p2:={lits[1]};\n"
        "    PROC main()\n        MoveL p1, v100, fine, tGrip\\WObj:=wTable;\n"
        "        MoveL p2, v100, fine, tHidden;\n    ENDPROC\nENDMODULE\n"
    )
    tools = (
        "MODULE Tools(SYSMODULE)\n"
        f"    PERS tooldata tGrip:={TOOL_TEXT};\n"
        f"    LOCAL PERS tooldata tHidden:={TOOL_TEXT};\n"
        '    TASK PERS wobjdata wTable:=[FALSE,TRUE,"",[[900,-250,300],[1,0,0,0]],'
        "[[0,0,0],[1,0,0,0]]];\nENDMODULE\n"
    )
    got = _by_name(_run(CAL, main_mod=main, tools_sys=tools))
    assert got["p1"][1] == "corrected"
    use = got["p1"][0].uses[0]
    assert use.tool is not None and use.work is not None
    np.testing.assert_allclose(use.work[:3, 3], [900, -250, 300])
    # A LOCAL tooldata of another module is not seen: named, with what to do.
    assert got["p2"][1] == "skipped"
    assert "tooldata tHidden is not declared in the given files: add the module" in got["p2"][2]
    # Without the tools module: the message names the tooldata and says to add its module.
    got = _by_name(_run(CAL, main_mod=main))
    assert "tooldata tGrip is not declared in the given files: add the module" in got["p1"][2]
    assert "wobjdata wTable is not declared" in got["p1"][2]


# -- ConfL\Off ----------------------------------------------------------------------------
def _olp(q: FloatArray, monitoring: str, dummy: tuple[int, ...] = (3, 3, 3, 7)) -> str:
    """An OLP module: main switches monitoring, then calls the path; every target after the
    first carries dummy confdata (the controller ignores it under \\Off)."""
    lits, poses = _targets(q)
    body = [lits[0]] + [_robtarget(p, dummy) for p in poses[1:]]
    decls = [f"    CONST robtarget Target_{10 * i}:={b};" for i, b in enumerate(body)]
    moves = [
        f"        Move{'J' if i == 0 else 'L'} Target_{10 * i},v500,z1,tGrip\\WObj:=wobj0;"
        for i in range(len(body))
    ]
    return "\n".join(
        [
            "MODULE OlpPath",
            f"    PERS tooldata tGrip:={TOOL_TEXT};",
            *decls,
            "    PROC main()",
            *[f"        {m};" for m in monitoring.split(";") if m],
            "        Path_10;",
            "    ENDPROC",
            "    PROC Path_10()",
            *moves,
            "    ENDPROC",
            "ENDMODULE",
            "",
        ]
    )


def test_confl_off_follows_the_previous_target_and_keeps_the_dummy_confdata() -> None:
    q = smooth_path(NOMINAL, 25, seed=4, step_deg=4.0)
    text = _olp(q, "ConfJ\\Off;ConfL\\Off")
    run = _run(CAL, olp_mod=text)
    assert not run.errors and run.exit_code == EXIT_OK
    # Each target on the branch the controller takes from the previous one: the planned one.
    nominal = np.array([c.nominal_joints_deg for c in run.corrections])
    np.testing.assert_allclose(nominal, q, atol=0.01)  # the written numbers' rounding
    out = run.outputs["olp.mod"].decode()
    assert out.count("[3,3,3,7]") == text.count("[3,3,3,7]") == 24
    assert _masked(out) == _masked(text)
    # Monitoring on (the default): the dummy confdata is demanded, and fits no solution.
    got = _by_name(_run(CAL, olp_mod=_olp(q, "")))
    assert got["Target_0"][1] == "corrected"
    assert got["Target_10"][2] == "no nominal solution in configuration [3,3,3,7]"


def test_under_confl_off_the_first_target_needs_its_confdata_or_a_moveabsj_before_it() -> None:
    q = smooth_path(NOMINAL, 6, seed=7)
    text = _olp(q, "ConfJ\\Off;ConfL\\Off")
    dummy_first = re.sub(r"\[-?\d+,-?\d+,-?\d+,\d\],\[9E", "[3,3,3,7],[9E", text, count=1)
    got = _by_name(_run(CAL, olp_mod=dummy_first))
    assert got["Target_0"][2].startswith(
        "no nominal solution in configuration [3,3,3,7], the first move under ConfL/ConfJ\\Off"
    )
    assert "where the robot is, which the program does not say" in got["Target_0"][2]
    assert "start the routine with a MoveAbsJ" in got["Target_0"][2]
    assert (
        got["Target_10"][2]
        == "the previous move's target Target_0 has no nominal joints to start from"
    )
    # The followers share one group in the summary, whatever their previous target's name.
    groups = {r["group"] for r in _run(CAL, olp_mod=dummy_first).rows() if "group" in r}
    assert len(groups) == 2, groups
    # Where only one solution lies within the joint limits, the robot has no other way to
    # reach the first target: it is taken whatever the ignored confdata says.
    limits = NOMINAL.limits_deg().copy()
    limits[:, 0] = np.maximum(limits[:, 0], q.min(axis=0) - 20.0)
    limits[:, 1] = np.minimum(limits[:, 1], q.max(axis=0) + 20.0)
    tight = replace(NOMINAL, joint_limits_deg=limits)
    cal = Calibration(tight, replace(CAL.calibrated, joint_limits_deg=limits), None, CAL.columns)
    run = _run(cal, olp_mod=dummy_first)
    assert run.exit_code == EXIT_OK, [c.reason for c in run.corrections if c.reason]
    np.testing.assert_allclose(run.corrections[0].nominal_joints_deg, q[0], atol=0.01)
    # Under ConfJ\On the same confdata is demanded: refused, not taken.
    honoured = dummy_first.replace("        ConfJ\\Off;\n", "")
    assert _by_name(_run(cal, olp_mod=honoured))["Target_0"][1] == "skipped"
    # A MoveAbsJ to where the path starts roots the chain: every target is corrected.
    joints = ",".join(f"{v:.4f}" for v in q[0])
    rooted = dummy_first.replace(
        "    PROC Path_10()\n",
        f"    PROC Path_10()\n        MoveAbsJ [[{joints}],{NO_AXES}],v500,fine,tGrip;\n",
    )
    run = _run(CAL, olp_mod=rooted)
    assert run.exit_code == EXIT_OK, [c.reason for c in run.corrections if c.reason]
    # So does one in main before the call (Path_10 is called from there only).
    in_main = dummy_first.replace(
        "        Path_10;\n",
        f"        MoveAbsJ [[{joints}],{NO_AXES}],v500,fine,tGrip;\n        Path_10;\n",
    )
    run = _run(CAL, olp_mod=in_main)
    assert run.exit_code == EXIT_OK, [c.reason for c in run.corrections if c.reason]
    # Called from two places: where the robot comes from is not one place; confdata again.
    twice = in_main.replace("        Path_10;\n", "        Path_10;\n        Path_10;\n")
    assert _by_name(_run(CAL, olp_mod=twice))["Target_0"][1] == "skipped"


def test_monitoring_is_followed_into_called_routines_or_left_when_unknown() -> None:
    q = smooth_path(NOMINAL, 4, seed=6)
    text = _olp(q, "ConfL\\Off").replace("        Path_10;\n", "        Path_10;\n" * 1)
    # ConfL off, ConfJ on: the MoveJ's confdata is honoured, the MoveLs follow the path.
    got = _by_name(_run(CAL, olp_mod=text))
    assert all(s == "corrected" for _, s, _ in got.values())
    # Called once with monitoring on and once off: unknown, left with that reason.
    both = text.replace("        ConfL\\Off;\n", "        Path_10;\n        ConfL\\Off;\n")
    got = _by_name(_run(CAL, olp_mod=both))
    assert got["Target_0"][1] == "corrected"
    assert got["Target_10"][1] == "skipped" and "ConfL/ConfJ unknown" in got["Target_10"][2]


def test_a_target_on_an_external_axis_is_left_with_that_reason() -> None:
    lits, poses = _targets(regular_poses(NOMINAL, 1, seed=8))
    conf = rapid_confdata(NOMINAL, regular_poses(NOMINAL, 1, seed=8))[0]
    track = _robtarget(poses[0], conf, "[1250.5,9E9,9E9,9E9,9E9,9E9]")
    text = (
        f"MODULE Track\n    PERS tooldata tGrip:={TOOL_TEXT};\n    PROC main()\n"
        f"        MoveAbsJ [[10,-20,160,0,40,0],[1250.5,9E9,9E9,9E9,9E9,9E9]],v100,fine,tGrip;\n"
        f"        MoveJ {track}\\ID:=1,v100,fine,tGrip;\n        MoveJ {lits[0]},v100,fine,tGrip;\n"
        "        MoveExtJ [[9E9,9E9,9E9,9E9,9E9,9E9],[1300,9E9,9E9,9E9,9E9,9E9]],v100,fine;\n"
        "    ENDPROC\nENDMODULE\n"
    )
    got = _by_name(_run(CAL, track_mod=text))
    _, status, reason = got["inline@5"]
    assert status == "skipped"
    assert reason.startswith(f"{EXTERNAL_AXIS_REASON} (eax_a = 1250.5): ")
    assert "external_axes = 0" in reason and "[controller]" in reason  # what to do
    assert got["inline@4"][1] == "corrected"  # a jointtarget's robot axes are the robot's
    assert got["inline@6"][1] == "corrected"
    assert "inline@7" not in got  # MoveExtJ moves the track only


def _no_external_axes(model: RobotModel) -> RobotModel:
    return replace(model, controller=replace(model.controller, external_axes=0))


def test_a_controller_without_external_axes_ignores_their_values() -> None:
    """An OLP module writes eax_a = 0 for an arm with no track (TACO's shape); the model says
    the controller has none (ABB ignores a value for an axis not connected): corrected, the
    eax text carried unchanged. Without that line in the model: left, as above."""
    q = regular_poses(NOMINAL, 3, seed=9)
    poses = planned_targets(NOMINAL, q, _tool(), np.eye(4))
    confs = rapid_confdata(NOMINAL, q)
    eax = "[0,9E9,9E9,9E9,9E9,9E9]"
    moves = "".join(
        f"MoveL {_robtarget(p, c, eax)},v150,z20,tGrip\\WObj:=wobj0;\n"
        for p, c in zip(poses, confs, strict=True)
    )
    head = f"MODULE MainModule\nPERS tooldata tGrip := {TOOL_TEXT};\nPROC Main()\n"
    text = f"{head}{moves}ENDPROC\nENDMODULE\n"
    left = _run(CAL, main_mod=text)
    assert [c.status for c in left.corrections] == ["skipped"] * 3
    nominal = _no_external_axes(NOMINAL)
    cal = Calibration(nominal, _no_external_axes(CAL.calibrated), None, np.zeros(0, dtype=int))
    run = _run(cal, main_mod=text)
    assert [c.status for c in run.corrections] == ["corrected"] * 3
    out = run.outputs["main.mod"].decode()
    assert out != text and out.count(eax) == 3
    same = Calibration(nominal, nominal, None, np.zeros(0, dtype=int))
    assert _run(same, main_mod=text).outputs["main.mod"].decode() == text


# -- refused ------------------------------------------------------------------------------
GOOD = "MODULE M\n    PROC main()\n        MoveAbsJ [[0,0,0,0,30,0],[9E9,9E9,9E9,9E9,9E9,9E9]],v100,fine,tool0;\n    ENDPROC\nENDMODULE\n"  # noqa: E501


@pytest.mark.parametrize(
    ("text", "line", "message"),
    [
        (GOOD.replace("ENDMODULE\n", ""), 5, "no ENDMODULE: the module is cut short"),
        (GOOD.replace("    ENDPROC\nENDMODULE\n", ""), 4, "PROC main (line 2) has no ENDPROC"),
        (GOOD[: GOOD.index(",v100")], 3, "PROC main (line 2) has no ENDPROC"),
        (GOOD.replace("tool0;", "tool0"), 3, "MoveAbsJ is not ended by ';'"),
        (GOOD + "{0;0}\nMODULE M2\nENDMODULE\n", 6, "text after ENDMODULE"),
        (GOOD.replace("ENDPROC\n", ""), 4, "ENDMODULE inside PROC main (line 2)"),
        (GOOD[: GOOD.index("30,0]")], 3, "PROC main (line 2) has no ENDPROC"),
    ],
)
def test_a_module_that_does_not_end_properly_is_refused(text: str, line: int, message: str) -> None:
    run = _run(CAL, cut_mod=text, ok_mod=GOOD.replace("MODULE M", "MODULE OK"))
    assert run.exit_code == EXIT_BAD_INPUT
    (err,) = run.errors
    assert (err.file, err.line) == ("cut.mod", line), str(err)
    assert message in str(err)
    assert "cut.mod" not in run.outputs and "ok.mod" in run.outputs


@pytest.mark.parametrize("number", ["9E+999", "1" * 5000, "-1e400"])
@pytest.mark.parametrize("field", ["confdata", "position"])
def test_an_absurd_number_is_a_clear_error_naming_file_and_line(number: str, field: str) -> None:
    conf = f"[{number},0,0,0]" if field == "confdata" else "[0,0,0,0]"
    pos = f"[{number},0,800]" if field == "position" else "[500,0,800]"
    text = (
        f"MODULE N\n    PROC main()\n        MoveL [{pos},[0,0,1,0],{conf},{NO_AXES}],"
        "v100,fine,tool0;\n    ENDPROC\nENDMODULE\n"
    )
    run = _run(CAL, n_mod=text)
    (err,) = run.errors
    assert (err.file, err.line) == ("n.mod", 3)
    assert "is out of range" in str(err) and len(str(err)) < 200
    with pytest.raises(ProgramError, match=r"line 2: number .* is out of range"):
        parse_program(
            "MODULE P\n    CONST jointtarget jt1:=[[0,0,0,0,"
            f"{number},0],{NO_AXES}];\n    PROC main()\n        MoveAbsJ jt1, v100, fine, "
            "tool0;\n    ENDPROC\nENDMODULE\n"
        )


# -- confdata -----------------------------------------------------------------------------
def test_cfx_reads_the_lower_arm_side_on_the_arm_itself() -> None:
    """ABB's cfx: the lower-arm bit is the arm's own side, so turning axis 2 alone (which
    carries the wrist centre from in front of axis 1 to behind it) never changes it, and
    configuration() gives back the branch signs cfx_of() was made from."""
    q = regular_poses(NOMINAL, 300, seed=11)
    sh, el, wr = branch_signs(NOMINAL, q)
    cfx = np.array([cfx_of(a, b, c) for a, b, c in zip(sh, el, wr, strict=True)])
    for i in range(len(q)):
        back = configuration([0, 0, 0, int(cfx[i])])
        assert (back.shoulder, back.elbow, back.wrist) == (sh[i], el[i], wr[i])
    swung = q.copy()
    swung[:, 1] = q[:, 1] - 120.0
    sh2, el2, wr2 = branch_signs(NOMINAL, swung)
    cfx2 = np.array([cfx_of(a, b, c) for a, b, c in zip(sh2, el2, wr2, strict=True)])
    crossed = sh2 != sh
    assert crossed.sum() > 20  # the swing did carry wrists across axis 1
    assert np.all((cfx2 // 2) % 2 == (cfx // 2) % 2)
    assert np.all(cfx2 % 2 == cfx % 2)
    assert [math.floor(v / 90) for v in (-0.5, 0.0, 89.9, 90.0, -90.0)] == [-1, 0, 0, 1, -1]


def test_parse_names_routine_data_and_keeps_inline_names_unique() -> None:
    lits, _ = _targets(regular_poses(NOMINAL, 2, seed=9))
    text = (
        f"MODULE C\n    PROC main()\n        MoveC {lits[0]},{lits[1]},v100,z1,tool0;\n"
        "    ENDPROC\nENDMODULE\n"
    )
    names = [
        t.name for t in RAPID.parse([Source.from_bytes("c.mod", text.encode())], FrameTables())
    ]
    assert names == ["inline@3", "inline@3#2"]
