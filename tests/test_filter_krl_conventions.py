"""KUKA conventions in the filter: the library model in KUKA's own angles, S and T, $FLANGE,
$config.dat read-only, unused points, the wrist singularity. Programs written here in the
shapes of real controller backups (&ACCESS header, FOLDs, DECL GLOBAL, E6POS with external
axes, Latin-1, CRLF, C_DIS/C_PTP, the geometric operator); no real file is copied."""

from __future__ import annotations

import re
import tomllib
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from calib.conventions import IDENTITY
from calib.filter.branches import branch_signs, flange_frames
from calib.filter.correct import Calibration
from calib.filter.run import EXIT_OK, filter_files
from calib.kinematics import FloatArray
from calib.models import RobotModel, model_from_mapping
from calib.programs.krl.filter import (
    CONFIG_DAT_READ_ONLY,
    NOT_LEFT_REASONS,
    UNUSED,
    WRIST_SINGULARITY,
    status_of,
    turn_of,
)
from calib.programs.rotations import (
    frame,
    invert,
    matrix_to_zyx_deg,
    rotation_angle_deg,
    zyx_deg_to_matrix,
)

LIBRARY = Path(__file__).parents[1] / "calib" / "robots" / "library"
TOOL = frame(np.array([12.0, -8.0, 310.0]), zyx_deg_to_matrix(0.0, -30.0, 0.0))  # in $FLANGE
BASE = frame(np.array([1500.0, -400.0, 250.0]), zyx_deg_to_matrix(20.0, 0.0, 0.0))
E6 = "E1 0.0,E2 0.0,E3 0.0,E4 0.0,E5 0.0,E6 0.0"


def _model(name: str) -> RobotModel:
    return model_from_mapping(tomllib.loads((LIBRARY / f"{name}.toml").read_text()))


def _r(deg: float) -> float:
    return float(np.deg2rad(deg))


def _kuka_chain(
    q: FloatArray, d1: float, a1: float, a2: float, a3: float, d4: float, d6: float
) -> FloatArray:
    """KUKA's $FLANGE from KUKA's angles, written as KUKA draws the arm: A1 turns about the
    base's -Z; A2, A3, A5 about the arm's left axis (+Y at A1 = 0); A4, A6 about the backward
    forearm axis (-X); all zeros: the arm stretched forward, $FLANGE parallel to the base."""

    def rot(axis: int, deg: float) -> np.ndarray:
        c, s = np.cos(_r(deg)), np.sin(_r(deg))
        m = np.eye(4)
        i, j = [(1, 2), (2, 0), (0, 1)][axis]
        m[i, i], m[i, j], m[j, i], m[j, j] = c, -s, s, c
        return m

    def tr(x: float, y: float, z: float) -> np.ndarray:
        return frame(np.array([x, y, z]), np.eye(3))

    out: FloatArray = (
        rot(2, -q[0])
        @ tr(a1, 0, d1)
        @ rot(1, q[1])
        @ tr(a2, 0, 0)
        @ rot(1, q[2])
        @ tr(d4, 0, a3)
        @ rot(0, -q[3])
        @ rot(1, q[4])
        @ rot(0, -q[5])
        @ tr(d6, 0, 0)
    )
    return out


def _table(model: RobotModel) -> RobotModel:
    """The model read in its table's angles (no [controller] conversion)."""
    return replace(model, controller=IDENTITY)


def _fk(model: RobotModel, q_deg: FloatArray) -> FloatArray:
    """$FLANGE (n, 4, 4) [mm] at KUKA's angles (n, 6) [deg]."""
    return flange_frames(_table(model), model.controller.to_table_deg(q_deg))


def _core_in_controller_angles() -> bool:
    """True once the filter's kinematics reads joints through the model's [controller]
    (the UR helper's change to calib/filter/branches.py)."""
    model = _model(MODEL)
    q = np.array([[30.0, -80.0, 100.0, 20.0, 40.0, 60.0]])
    return bool(np.allclose(flange_frames(model, q), _fk(model, q), atol=1e-6))


@pytest.mark.parametrize(
    ("name", "dims"),
    [
        ("kuka-kr210-r2700-prime", (675, 350, 1150, -41, 1200, 240)),
        ("kuka-kr210-r2700-2", (645, 330, 1150, 115, 1220, 215)),
        ("kuka-kr16", (675, 260, 680, -35, 670, 158)),
        ("kuka-kr6-r900", (400, 25, 455, 35, 420, 80)),
    ],
)
def test_library_tables_are_kukas_chain_in_kukas_angles(name: str, dims: tuple[float, ...]) -> None:
    model = _model(name)
    assert model.controller.maker == "kuka"
    assert model.controller.direction == (-1, 1, 1, -1, 1, -1)
    rng = np.random.default_rng(1)
    q = rng.uniform(-170, 170, size=(50, 6))
    # $FLANGE: Z out of the flange, X down with all axes at 0 (the link-6 frame turned by
    # Ry(90 deg), as ROS-Industrial's tool0 and the real pair of docs/robots-kuka.md).
    flange = frame(np.zeros(3), zyx_deg_to_matrix(0.0, 90.0, 0.0))
    want = np.array([_kuka_chain(qi, *dims) @ flange for qi in q])
    assert float(np.max(np.abs(_fk(model, q) - want))) < 1e-9


def _regular(model: RobotModel, n: int) -> FloatArray:
    rng = np.random.default_rng(7)
    lim = np.asarray(model.joint_limits_deg)
    out: list[FloatArray] = []
    while len(out) < n:
        q = rng.uniform(lim[:, 0] * 0.8, lim[:, 1] * 0.8)
        if min(abs(q[4]), abs(q[0]), abs(q[3]), abs(q[5])) > 12 and abs(q[4]) < 110:
            out.append(q)
    return np.array(out)


def _agg(pose: FloatArray) -> str:
    a, b, c = matrix_to_zyx_deg(pose[:3, :3])
    x, y, z = pose[:3, 3]
    return f"X {x:.3f},Y {y:.3f},Z {z:.3f},A {a:.4f},B {b:.4f},C {c:.4f}"


def _program(model: RobotModel) -> list[tuple[str, bytes]]:
    """``cell.src``/``cell.dat``/``$config.dat`` of Cartesian and joint points of one arm."""
    q = _regular(model, 8)
    poses = invert(BASE) @ _fk(model, q) @ TOOL
    sh, el, _ = branch_signs(_table(model), model.controller.to_table_deg(q))
    wr = np.where(q[:, 4] >= 0, 1, -1)  # S bit 2 follows KUKA's A5
    dat = [
        "&ACCESS RVP",
        "&REL 7",
        "DEFDAT  CELL",
        ";FOLD EXTERNAL DECLARATIONS;%{PE}%MKUKATPBASIS",
        ";ENDFOLD",
    ]
    src = [
        "&ACCESS RVP",
        "&REL 7",
        "DEF cell( )",
        ";FOLD INI",
        "BAS (#INITMOV,0 )",
        ";ENDFOLD (INI)",
    ]
    for i in range(5):
        s, t = status_of(sh[i], el[i], wr[i]), turn_of(q[i])
        dat.append(f"DECL E6POS XP{i}={{{_agg(poses[i])},S {s},T {t},{E6}}}")
        dat.append(f'DECL FDAT FP{i}={{TOOL_NO 1,BASE_NO 2,IPO_FRAME #BASE,POINT2[] " "}}')
        move = ("PTP", "LIN", "PTP", "LIN", "PTP")[i]
        approx = " C_DIS" if move == "LIN" else " C_PTP"
        src.append(f";FOLD {move} P{i} Vel=2 m/s CPDAT{i} Tool[1]:Greifer Base[2]:Tisch;%{{PE}}")
        src.append(f"FDAT_ACT=FP{i}")
        src.append(f"{move} XP{i}{approx}")
        src.append(";ENDFOLD")
    # Unused points: one with its own FDAT (corrected), one without (named).
    s, t = status_of(sh[5], el[5], wr[5]), turn_of(q[5])
    dat.append(f"DECL E6POS XSPARE={{{_agg(poses[5])},S {s},T {t},{E6}}}")
    dat.append("DECL FDAT FSPARE={TOOL_NO 1,BASE_NO 2,IPO_FRAME #BASE}")
    dat.append(f"DECL E6POS XORPHAN={{{_agg(poses[6])},S 2,T 0,{E6}}}")
    # Joint targets, a global one, a HOME at A5 = 0 and a geometric-operator target.
    for i in (6, 7):
        joints = ",".join(f"A{j + 1} {q[i, j]:.4f}" for j in range(6))
        dat.append(f"DECL GLOBAL E6AXIS XJ{i}={{{joints},{E6}}}")
        src.append(f"PTP XJ{i} C_PTP")
    dat.append(f"DECL E6AXIS XHOMELOCAL={{A1 0.0,A2 -90.0,A3 90.0,A4 0.0,A5 0.0,A6 0.0,{E6}}}")
    src.append("PTP XHOMELOCAL")
    src.append("PTP XHOME")
    dat.append(f"DECL E6POS XOFS={{{_agg(poses[7])},S 2,T 0,{E6}}}")
    src.append("$TOOL=TOOL_DATA[1]")
    src.append("$BASE=BASE_DATA[2]")
    src.append("LIN XOFS:{X 0.0,Y 0.0,Z 10.0,A 0.0,B 0.0,C 0.0} ; über dem Teil")
    src.append("END")
    dat.append("ENDDAT")
    cfg = [
        "&ACCESS RVP",
        "&PARAM EDITMASK = *",
        "DEFDAT  $CONFIG",
        ";FOLD BASISTECH GLOBALS",
        f"DECL E6AXIS XHOME={{A1 0.0,A2 -90.0000,A3 90.0000,A4 0.0,A5 0.0,A6 0.0,{E6}}}",
        ";ENDFOLD (BASISTECH GLOBALS)",
        f"TOOL_DATA[1]={{{_agg(TOOL)}}} ; Greifer für Bleche",
        f"BASE_DATA[2]={{{_agg(BASE)}}}",
        "ENDDAT",
    ]

    def crlf(lines: list[str]) -> bytes:
        return ("\r\n".join(lines) + "\r\n").encode("latin-1")

    return [("cell.src", crlf(src)), ("cell.dat", crlf(dat)), ("$config.dat", crlf(cfg))]


def _cal(nominal: RobotModel, row: int = 0, col: int = 2, delta: float = 0.0) -> Calibration:
    table = nominal.dh_table.copy()
    table[row, col] += delta
    return Calibration(nominal, replace(nominal, dh_table=table), None, np.zeros(0, dtype=int))


_NUM = re.compile(rb"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")
_POINT = re.compile(rb"DECL (?:GLOBAL )?(E6POS|E6AXIS) (\w+)=\{([^}]*)\}")


def _points(data: bytes) -> dict[str, dict[str, float]]:
    out = {}
    for _, name, body in _POINT.findall(data):
        out[name.decode()] = {
            k.decode(): float(v) for k, v in re.findall(rb"(\w+) ([-\d.]+)", body)
        }
    return out


def _pose(p: dict[str, float]) -> FloatArray:
    return frame(np.array([p["X"], p["Y"], p["Z"]]), zyx_deg_to_matrix(p["A"], p["B"], p["C"]))


MODEL = "kuka-kr210-r2700-prime"


@pytest.fixture(params=["kuka-angles", "table-angles"])
def model(request: pytest.FixtureRequest) -> RobotModel:
    """The library model read as the pendant counts (needs the kinematics in controller
    angles), and its table read in its own angles (runs today: every rule but the senses)."""
    if request.param == "table-angles":
        return _table(_model(MODEL))
    if not _core_in_controller_angles():
        pytest.skip("calib/filter/branches.py does not read joints through [controller] yet")
    return _model(MODEL)


def test_nominal_calibration_changes_no_byte_and_names_every_left_target(
    model: RobotModel,
) -> None:
    files = _program(model)
    run = filter_files(_cal(model), files)
    assert run.errors == [] and run.outputs == dict(files)
    rows = {r["name"]: r for r in run.rows()}
    for name in ("XP0", "XP1", "XP2", "XP3", "XP4", "XSPARE", "XJ6", "XJ7"):
        assert rows[name]["status"] == "corrected", rows[name]
    assert rows["XORPHAN"]["reason"] == UNUSED
    assert rows["XHOMELOCAL"]["reason"] == WRIST_SINGULARITY
    assert rows["XHOME"]["reason"] == CONFIG_DAT_READ_ONLY
    assert "used in the expression" in rows["XOFS"]["reason"]
    left = [r for r in run.rows() if r["status"] != "corrected"]
    assert {r["name"] for r in left} == {"XORPHAN", "XHOMELOCAL", "XHOME", "XOFS"}


def test_unused_points_and_config_dat_do_not_make_exit_3(model: RobotModel) -> None:
    files = [f for f in _program(model)]
    # Only the unused point and $config.dat's XHOME are left.
    files[0] = (
        "cell.src",
        files[0][1].replace(b"PTP XHOMELOCAL\r\n", b"").replace(b"LIN XOFS:", b";LIN XOFS:"),
    )
    dat = (
        files[1][1]
        .replace(b"DECL E6AXIS XHOMELOCAL", b";DECL E6AXIS XHOMELOCAL")
        .replace(b"DECL E6POS XOFS", b";DECL E6POS XOFS")
    )
    files[1] = ("cell.dat", dat)
    run = filter_files(_cal(model, delta=0.3), files)
    assert {r["reason"] for r in run.rows() if r["status"] != "corrected"} <= set(NOT_LEFT_REASONS)
    assert run.exit_code == EXIT_OK


def test_whole_arm_shift_moves_every_cartesian_target_by_it_and_keeps_s_t(
    model: RobotModel,
) -> None:
    files = _program(model)
    run = filter_files(_cal(model, 0, 2, 0.3), files)  # joint 1's d + 0.3 mm
    out = run.outputs
    assert out["$config.dat"] == dict(files)["$config.dat"]
    old, new = _points(dict(files)["cell.dat"]), _points(out["cell.dat"])
    moved = 0
    for r in run.rows():
        if r["status"] != "corrected" or r["kind"] != "cartesian":
            continue
        a, b = old[r["name"]], new[r["name"]]
        shift = float(np.linalg.norm(_pose(a)[:3, 3] - _pose(b)[:3, 3]))
        assert abs(shift - 0.3) <= 0.002, (r["name"], shift)
        assert (a["S"], a["T"]) == (b["S"], b["T"])
        moved += 1
    assert moved == 6
    for name in ("cell.dat", "cell.src"):  # every byte outside the numbers kept
        assert _NUM.sub(b"#", out[name]) == _NUM.sub(b"#", dict(files)[name])
    cal = _cal(model, 0, 2, 0.3).calibrated
    for name in ("XJ6", "XJ7"):  # the shifted arm reaches the nominal flange with the new joints
        q_old = np.array([[old[name][f"A{j}"] for j in range(1, 7)]])
        q_new = np.array([[new[name][f"A{j}"] for j in range(1, 7)]])
        gap = _fk(cal, q_new)[0, :3, 3] - _fk(model, q_old)[0, :3, 3]
        assert float(np.linalg.norm(gap)) < 0.005 and not np.array_equal(q_old, q_new)


def test_base_turn_turns_targets_and_changes_only_a1_of_joint_targets(model: RobotModel) -> None:
    files = _program(model)
    run = filter_files(_cal(model, 0, 3, 0.05), files)  # joint 1's theta + 0.05 deg
    old, new = _points(dict(files)["cell.dat"]), _points(run.outputs["cell.dat"])
    assert run.outputs["$config.dat"] == dict(files)["$config.dat"]
    for r in run.rows():
        if r["status"] != "corrected":
            continue
        a, b = old[r["name"]], new[r["name"]]
        if r["kind"] == "cartesian":
            turn = float(rotation_angle_deg(_pose(a)[None, :3, :3], _pose(b)[None, :3, :3])[0])
            assert abs(turn - 0.05) < 5e-4, (r["name"], turn)
            assert (a["S"], a["T"]) == (b["S"], b["T"])
        else:
            # The table's +0.05 deg about its z1 is undone by -0.05 deg of it: +0.05 deg of
            # KUKA's A1, which turns the other way (direction -1).
            step = -0.05 * model.controller.direction[0]
            assert b["A1"] == pytest.approx(a["A1"] + step, abs=1e-4)
            assert [a[f"A{j}"] for j in range(2, 7)] == [b[f"A{j}"] for j in range(2, 7)]


def test_external_axes_not_zero_leave_a_cartesian_target_named() -> None:
    model = _table(_model(MODEL))
    files = dict(_program(model))
    dat = re.sub(rb"(DECL E6POS XP1=\{[^}]*?)E1 0\.0", rb"\1E1 1250.0", files["cell.dat"])
    files["cell.dat"] = dat
    run = filter_files(_cal(model, 0, 2, 0.3), list(files.items()))
    reason = {r["name"]: r["reason"] for r in run.rows()}
    assert reason["XP1"].startswith("external axes E1 not 0")
    line = re.compile(rb"DECL E6POS XP1=[^\r]*")
    assert line.search(run.outputs["cell.dat"]).group() == line.search(dat).group()  # type: ignore[union-attr]
