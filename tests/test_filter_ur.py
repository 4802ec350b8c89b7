"""The filter on UR programs (UR's offset wrist, nearest-q rule) and the controller's joint
conventions at the filter's kinematics boundary (calib/filter/kin.py).

The URScript below is written by this project in the shapes of real PolyScope exports
(``def``…``end``, ``global NAME_p=p[…]`` / ``global NAME_q=[…]`` pairs,
``movej(get_inverse_kin(NAME_p, qnear=NAME_q), …)``, ``$ n "…"`` lines, ``set_tcp``) and of
hand-written scripts (a ``p[…]`` variable, ``pose_trans`` of a feature, inline literals);
bench/ur_factory.md names the real exports these shapes were checked on.
"""

from __future__ import annotations

import tomllib
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from calib.conventions import JointConvention
from calib.filter.branches import branch_signs
from calib.filter.correct import Calibration, correct_targets
from calib.filter.kin import flange_frames, to_controller_deg
from calib.filter.run import filter_files
from calib.kinematics import FloatArray
from calib.models import RobotModel, builtin_model, model_from_mapping
from calib.programs.rotations import matrix_to_rotvec
from calib.programs.sites import Configuration, Target, Use

LIBRARY = Path(__file__).resolve().parent.parent / "calib" / "robots" / "library"


def _ur10e() -> RobotModel:
    return model_from_mapping(tomllib.loads((LIBRARY / "ur10e.toml").read_text("utf-8")))


def _cal(nominal: RobotModel, change: tuple[int, int, float] | None = None) -> Calibration:
    table = nominal.dh_table.copy()
    if change is not None:
        j, col, delta = change
        table[j, col] += delta
    cal = RobotModel("cal", nominal.convention, table, nominal.joint_limits_deg)
    return Calibration(nominal, cal, None, np.zeros(0, dtype=int))


def _p(frame: FloatArray) -> str:
    v = [*(frame[:3, 3] / 1000.0), *matrix_to_rotvec(frame[:3, :3])]
    return (
        "p["
        + ", ".join(f"{x:.12f}".replace("0.", ".", 1) if abs(x) < 1 else f"{x:.12f}" for x in v)
        + "]"
    )


def _q(q_deg: FloatArray) -> str:
    return "[" + ", ".join(repr(float(x)) for x in np.deg2rad(q_deg)) + "]"


# Waypoint joints [deg] (the controller's): elbow up and down, a wrist near q5 = 0, a turn.
WAYPOINTS = {
    "Approach": [-20.0, -80.0, 100.0, -110.0, -90.0, 15.0],
    "Pick": [-25.0, -70.0, 95.0, -115.0, -90.0, 10.0],
    "Under": [30.0, -120.0, -60.0, 200.0, 70.0, -30.0],
    "Flat": [10.0, -100.0, 80.0, -70.0, 0.002, 40.0],
    "Turned": [-200.0, -90.0, 110.0, -100.0, -80.0, 300.0],
}
TCP = np.array([[1.0, 0, 0, 0.0], [0, 1.0, 0, -10.0], [0, 0, 1.0, 195.0], [0, 0, 0, 1.0]])


def _script(model: RobotModel) -> str:
    lines = ["def Pick_Place():", "  # taught on the pendant; home below written by hand"]
    lines.append("  set_tcp(p[0.0,-0.01,0.195,0.0,0.0,0.0])")
    for name, q in WAYPOINTS.items():
        pose = flange_frames(model, np.array([q]))[0] @ TCP
        lines.append(f"  global {name}_p={_p(pose)}")
        lines.append(f"  global {name}_q={_q(np.array(q))}")
    home = flange_frames(model, np.array([[-22.0, -85.0, 105.0, -110.0, -90.0, 12.0]]))[0] @ TCP
    lines.append(f"  home = {_p(home)}")
    lines.append("  global Plane_1=p[.6,-.4,.25,0.0,0.0,.349065850]")
    lines.append('  $ 1 "Robot Program"')
    for k, name in enumerate(WAYPOINTS):
        lines.append(f'  $ {k + 2} "{name}" "breakAfter"')
        lines.append(
            f"  movej(get_inverse_kin({name}_p, qnear={name}_q), a=1.3962634015954636, "
            "v=1.0471975511965976)"
        )
        if name == "Pick":
            lines.append("  movel(home, a=1.2, v=0.25)")
    lines.append("end")
    return "\n".join(lines) + "\n"


@pytest.fixture(scope="module")
def ur10e() -> RobotModel:
    return _ur10e()


def _run(cal: Calibration, text: str, name: str = "pick.script"):  # type: ignore[no-untyped-def]
    data = text.encode()
    run = filter_files(cal, [(name, data)])
    assert run.errors == []
    return run, data


def test_identity_calibration_changes_no_byte_and_corrects_every_target(ur10e: RobotModel) -> None:
    run, data = _run(_cal(ur10e), _script(ur10e))
    assert run.outputs["pick.script"] == data
    by = {t.name: c for t, c in zip(run.targets, run.corrections, strict=True)}
    assert set(by) == {f"{n}_{s}" for n in WAYPOINTS for s in "pq"} | {"home"}
    assert all(c.status == "corrected" for c in by.values()), {
        n: c.reason for n, c in by.items() if c.status != "corrected"
    }
    # UR's rule: the nominal solution of NAME_p is the one nearest NAME_q (its own joints).
    for name, q in WAYPOINTS.items():
        got = by[f"{name}_p"].nominal_joints_deg
        assert got is not None
        np.testing.assert_allclose(got, q, atol=1e-6)
    # home (movel, no q): the solution nearest the previous move's (Pick's) joints.
    got = by["home"].nominal_joints_deg
    assert got is not None
    np.testing.assert_allclose(got, [-22.0, -85.0, 105.0, -110.0, -90.0, 12.0], atol=1e-6)


def test_a_shift_of_the_whole_arm_moves_every_pose_by_it(ur10e: RobotModel) -> None:
    run, data = _run(_cal(ur10e, (0, 2, 0.3)), _script(ur10e))  # d1 + 0.3 mm
    for t, c in zip(run.targets, run.corrections, strict=True):
        assert c.status == "corrected", (t.name, c.reason)
        if t.kind == "cartesian":
            assert abs(c.shift_mm - 0.3) < 0.002 and c.shift_deg < 1e-4, t.name
            assert c.pose is not None and t.pose is not None
            np.testing.assert_allclose(c.pose[:3, 3] - t.pose[:3, 3], [0, 0, -0.3], atol=2e-3)
    out = run.outputs["pick.script"].decode()
    assert out.count("\n") == data.decode().count("\n")


def test_a_turn_about_the_base_changes_only_joint_1_of_the_waypoints_q(ur10e: RobotModel) -> None:
    run, _ = _run(_cal(ur10e, (0, 3, 0.05)), _script(ur10e))  # theta1 + 0.05 deg
    by = {t.name: (t, c) for t, c in zip(run.targets, run.corrections, strict=True)}
    for name in WAYPOINTS:
        if name == "Flat":
            continue
        t, c = by[f"{name}_q"]
        assert c.status == "corrected" and c.joints_deg is not None and t.joints_deg is not None
        delta = c.joints_deg - t.joints_deg
        np.testing.assert_allclose(delta, [-0.05, 0, 0, 0, 0, 0], atol=1e-6)
        _, cp = by[f"{name}_p"]
        assert abs(cp.shift_deg - 0.05) < 1e-4, name


def test_a_correction_that_flips_the_wrist_is_left_with_the_reason(ur10e: RobotModel) -> None:
    run, data = _run(_cal(ur10e, (4, 3, 0.01)), _script(ur10e))  # theta5 + 0.01 deg
    by = {t.name: (t, c) for t, c in zip(run.targets, run.corrections, strict=True)}
    _, flat = by["Flat_p"]
    # J5 = 0.002 deg: the wrist singularity, named with the flip the correction would make.
    assert flat.status == "skipped" and flat.reason.startswith("wrist singularity (J5 = 0.002")
    assert "puts J5 at -" in flat.reason and "the other wrist" in flat.reason
    _, flat_q = by["Flat_q"]
    assert flat_q.status == "skipped" and "not corrected" in flat_q.reason
    out = run.outputs["pick.script"].decode().splitlines()
    old = data.decode().splitlines()
    for k, line in enumerate(old):
        if line.lstrip().startswith(("global Flat_p", "global Flat_q")):
            assert out[k] == line
    assert by["Pick_p"][1].status == "corrected"


def test_controller_conventions_give_the_same_corrections_in_their_own_angles() -> None:
    """A Fanuc-like convention (J3 reversed, J3 coupled to J2) on the same arm: every
    correction equals the identity case's, the joints expressed in the controller's angles."""
    base = builtin_model("hsr-jr680")
    limits = np.tile([-179.0, 179.0], (6, 1))
    ident = replace(base, joint_limits_deg=limits)
    conv = replace(ident, controller=JointConvention("fanuc", (1, 1, -1, 1, 1, 1), ((2, 1, 1.0),)))
    rng = np.random.default_rng(8)
    q_table = rng.uniform(-50.0, 50.0, size=(12, 6))
    q_table[:, 4] = rng.choice([-1.0, 1.0], 12) * rng.uniform(20.0, 60.0, 12)
    q_ctrl = to_controller_deg(conv, q_table)
    assert not np.allclose(q_ctrl, q_table)
    np.testing.assert_allclose(
        flange_frames(conv, q_ctrl), flange_frames(ident, q_table), atol=1e-9
    )
    signs = np.stack(branch_signs(ident, q_table), axis=1)
    np.testing.assert_array_equal(np.stack(branch_signs(conv, q_ctrl), axis=1), signs)
    table = ident.dh_table.copy()
    table[1, 1] += 1.5
    table[2, 3] += 0.05
    table[4, 0] += 0.03

    def targets(model: RobotModel, q: FloatArray) -> list[Target]:
        out = []
        eye = np.eye(4)
        for i, pose in enumerate(flange_frames(model, q)):
            use = Use("s", i + 1, "tool0", "wobj0", eye, eye)
            cfg = Configuration(
                shoulder=int(signs[i, 0]), elbow=int(signs[i, 1]), wrist=int(signs[i, 2])
            )
            out.append(
                Target("s", i + 1, f"p{i}", "cartesian", pose=pose, configuration=cfg, uses=[use])
            )
            out.append(Target("s", i + 1, f"j{i}", "joint", joints_deg=q[i]))
        return out

    got = {}
    for model, q in ((ident, q_table), (conv, q_ctrl)):
        cal = Calibration(
            model, RobotModel("cal", "dh", table, limits), None, np.zeros(0, dtype=int)
        )
        got[model.controller.maker] = correct_targets(cal, targets(model, q))
    for a, b in zip(got[None], got["fanuc"], strict=True):
        assert a.status == b.status == "corrected", (a.reason, b.reason)
        assert a.joints_deg is not None and b.joints_deg is not None
        np.testing.assert_allclose(b.joints_deg, to_controller_deg(conv, a.joints_deg), atol=1e-6)
        assert abs(a.shift_mm - b.shift_mm) < 1e-6
        if a.pose is not None:
            assert b.pose is not None
            np.testing.assert_allclose(b.pose, a.pose, atol=1e-6)
    assert max(c.shift_mm for c in got[None]) > 0.5  # not vacuous


HAND_WRITTEN = """\
def draw():
  # hand-written: a feature, relative moves, variables, inline literals
  feature = p[.45, -.2, .05, 0.0, 0.0, 1.5707963]
  accel_mss = 1.2
  rapid_ms = 0.25
  blend_radius_m = 0.001
  start = {start}
  movej({home_q}, a=1.4, v=1.05)
  movel(start, a=1.2, v=0.25)
  movel(pose_trans(feature, {local}), accel_mss, v=rapid_ms, t=0, r=blend_radius_m)
  movel(pose_trans(get_actual_tcp_pose(), p[0.0, 0.0, -0.02, 0.0, 0.0, 0.0]), a=0.1, v=0.1)
  movel(pose_trans(feature, pose_trans(pose_inv({local}), {local})), a=2.5, v=0.3)
  start_pos=get_forward_kin()
  target_pos=pose_trans(start_pos,p[0.0, 0.0, 0.1, 0.0, 0.0, 0.0])
  movel(target_pos, a=1.2, v=0.25)
end
"""


def test_hand_written_script_shapes(ur10e: RobotModel) -> None:
    """Variables, a feature, inline literals: corrected; a move relative to the current
    pose and computed poses: left with the reason or not targets at all; no traceback."""
    home = np.array([[-20.0, -80.0, 100.0, -110.0, -90.0, 15.0]])
    start = flange_frames(ur10e, np.array([[-22.0, -85.0, 105.0, -110.0, -90.0, 12.0]]))[0]
    feature = np.eye(4)
    feature[:3, 3] = (450.0, -200.0, 50.0)
    c, s = np.cos(1.5707963), np.sin(1.5707963)
    feature[:2, :2] = [[c, -s], [s, c]]
    world = flange_frames(ur10e, np.array([[-18.0, -82.0, 98.0, -108.0, -91.0, 14.0]]))[0]
    local = np.linalg.inv(feature) @ world
    text = HAND_WRITTEN.format(start=_p(start), home_q=_q(home[0]), local=_p(local))
    run, data = _run(_cal(ur10e, (0, 2, 0.3)), text, "draw.script")
    rows = {(t.line, t.name): c for t, c in zip(run.targets, run.corrections, strict=True)}
    by = {name: c for (_line, name), c in rows.items()}
    assert by["start"].status == "corrected" and abs(by["start"].shift_mm - 0.3) < 0.002
    assert by["inline@8"].status == "corrected"  # movej's joint list
    assert by["inline@10"].status == "corrected" and abs(by["inline@10"].shift_mm - 0.3) < 0.002
    relative = by["inline@11"]
    assert relative.status == "skipped" and "get_actual_tcp_pose()" in relative.reason
    assert run.exit_code == 3
    assert len(run.outputs["draw.script"].splitlines()) == len(data.splitlines())


@pytest.mark.parametrize(
    "text",
    [
        "/PROG  PICK\n/ATTR\nOWNER = MNEDITOR;\n/MN\n   1:J P[1] 100% FINE    ;\n/POS\n"
        "P[1]{\n   GP1:\n\tUF : 0, UT : 1,\t\tCONFIG : 'N U T, 0, 0, 0',\n"
        "\tX =   500.000  mm,\tY =     0.000  mm,\tZ =   400.000  mm,\n"
        "\tW =   180.000 deg,\tP =     0.000 deg,\tR =     0.000 deg\n};\n/END\n",
        "&ACCESS RVP\nDEF pick( )\n  PTP XHOME\n  LIN XP1\nEND\n",
    ],
    ids=["fanuc-ls", "krl-src"],
)
def test_another_controllers_program_named_script_is_refused(ur10e: RobotModel, text: str) -> None:
    run = filter_files(_cal(ur10e), [("job.script", text.encode())])
    assert run.exit_code == 2 and "job.script" not in run.outputs
    assert "the content is not urscript" in str(run.errors[0])


def test_a_first_pose_without_joint_reference_is_left_with_the_reason(ur10e: RobotModel) -> None:
    pose = flange_frames(ur10e, np.array([[-20.0, -80.0, 100.0, -110.0, -90.0, 15.0]]))[0]
    run, data = _run(
        _cal(ur10e, (0, 2, 0.3)), f"def a():\n  movel({_p(pose)}, a=1.2, v=0.25)\nend\n"
    )
    (c,) = run.corrections
    assert c.status == "skipped" and "no joint reference" in c.reason and "ambiguous" in c.reason
    assert run.outputs["pick.script"] == data


def test_joint_conventions_are_converted_at_the_kinematics_boundary_only() -> None:
    """calib/filter/kin.py is the one place the filter converts joint angles: no dialect,
    no other module of the filter reads the model's convention."""
    root = Path(__file__).resolve().parent.parent / "calib" / "filter"
    for path in sorted(root.glob("*.py")):
        if path.name in ("kin.py",):
            continue
        text = path.read_text("utf-8")
        for word in (".controller", "JointConvention", "conventions import"):
            assert word not in text, f"{path.name} converts joint angles itself ({word})"
