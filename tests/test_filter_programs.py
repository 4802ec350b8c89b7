"""cablecal filter, dialects: fixtures parse, nothing but numbers changes, bad input named."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from calib.filter.correct import Calibration
from calib.filter.run import EXIT_BAD_INPUT, EXIT_LEFT, filter_files
from calib.models import RobotModel, builtin_model
from calib.programs.dialects import dialect_for
from calib.programs.rapid.filter import DIALECT as RAPID
from calib.programs.sites import FilterInputError, FrameTables, Num, Source, format_number
from calib.programs.urscript.filter import DIALECT as URSCRIPT

FIXTURES = Path(__file__).parent / "fixtures" / "programs"
_NUMBER = re.compile(rb"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")


@pytest.fixture(scope="module")
def nominal() -> RobotModel:
    return builtin_model("hsr-jr680")


def _identity(nominal: RobotModel) -> Calibration:
    return Calibration(nominal, nominal, None, np.zeros(0, dtype=int))


def _fixture_files() -> list[tuple[str, bytes]]:
    return [(p.name, p.read_bytes()) for p in sorted(FIXTURES.iterdir()) if p.is_file()]


def _numbers_blanked(data: bytes) -> bytes:
    return _NUMBER.sub(b"#", data)


def test_calibration_equal_to_nominal_changes_no_byte(nominal: RobotModel) -> None:
    run = filter_files(_identity(nominal), _fixture_files())
    assert run.errors == []
    for name, data in _fixture_files():
        assert run.outputs[name] == data, name
    # Not vacuous: the targets were corrected (by nothing), not skipped.
    corrected = {
        t.file for t, c in zip(run.targets, run.corrections, strict=True) if c.status == "corrected"
    }
    assert corrected == {"cell_a.mod", "station_b.prg", "polyscope_c.script", "plain_d.urscript"}
    assert all(c.shift_mm < 1e-6 for c in run.corrections if c.status == "corrected")


def test_a_real_calibration_changes_only_numbers_and_keeps_encoding_and_crlf(
    nominal: RobotModel,
) -> None:
    calibrated = builtin_model("hsr-jr680")
    table = calibrated.dh_table.copy()
    table[1, 1] += 1.5  # a2 longer by 1.5 mm
    table[2, 3] += 0.05  # theta3 off by 0.05 deg
    cal = Calibration(
        nominal,
        RobotModel("cal", "dh", table, nominal.joint_limits_deg),
        None,
        np.zeros(0, dtype=int),
    )
    files = _fixture_files()
    run = filter_files(cal, files)
    assert run.errors == []
    for name, data in files:
        out = run.outputs[name]
        assert _numbers_blanked(out) == _numbers_blanked(data), name
    station = run.outputs["station_b.prg"]
    assert station != dict(files)["station_b.prg"]
    assert station.count(b"\r\n") == dict(files)["station_b.prg"].count(b"\r\n")
    assert "Schweißstation".encode("latin-1") in station  # still Latin-1, not UTF-8
    assert run.outputs["notes_e.mod"] == dict(files)["notes_e.mod"]
    assert run.outputs["tools_b.sys"] == dict(files)["tools_b.sys"]  # tool data untouched


def test_rapid_targets_uses_and_frames() -> None:
    src = [Source.from_bytes(n, d) for n, d in _fixture_files() if n.endswith((".prg", ".sys"))]
    targets = {t.name: t for t in RAPID.parse(src, FrameTables())}
    assert set(targets) == {"pB1", "pB2", "pB3", "pB4", "pB5", "jB"}
    assert targets["pB2"].line == 10  # a declaration over four lines
    assert [u.line for u in targets["pB3"].uses] == [24, 25]
    gun = targets["pB1"].uses[0]
    assert gun.tool_name == "tGun" and gun.work_name == "wTable" and gun.problem == ""
    assert gun.tool is not None and gun.work is not None
    np.testing.assert_allclose(gun.tool[:3, 3], [0, 15, 240])
    # wobjdata: uframe · oframe; uframe turned 90 deg about z, oframe shifted (-40, 60, 5).
    np.testing.assert_allclose(gun.work[:3, 3], [1050 - 60, 200 - 40, 385], atol=1e-3)
    assert "wMissing is not declared" in targets["pB4"].uses[0].problem
    assert targets["pB5"].uses == []
    cell = Source.from_bytes("cell_a.mod", (FIXTURES / "cell_a.mod").read_bytes())
    names = [t.name for t in RAPID.parse([cell], FrameTables())]
    assert names == ["pApproach", "pEdge", "pPath{1}", "pPath{2}", "pPath{3}", "jHome", "inline@32"]
    by = {t.name: t for t in RAPID.parse([cell], FrameTables())}
    assert [u.line for u in by["pEdge"].uses] == [27, 31]  # direct and through Offs()
    assert all(len(by[f"pPath{{{k}}}"].uses) == 1 for k in (1, 2, 3))  # pPath{nIdx}


def test_urscript_pairs_tools_and_features() -> None:
    src = Source.from_bytes("c.script", (FIXTURES / "polyscope_c.script").read_bytes())
    targets = {t.name: t for t in URSCRIPT.parse([src], FrameTables())}
    assert targets["Waypoint_1_q"].follows == "Waypoint_1_p"
    assert targets["Waypoint_2_q"].follows == "Waypoint_2_p"
    cfg = targets["Waypoint_1_p"].configuration
    assert cfg is not None and cfg.nearest_deg is not None
    np.testing.assert_allclose(cfg.nearest_deg, [-30, -45, 205, 15, 50, -20], atol=1e-9)
    use = targets["Waypoint_2_p"].uses[0]
    assert use.tool is not None
    np.testing.assert_allclose(use.tool[:3, 3], [0, -10, 195])
    inline = targets["inline@24"]
    assert inline.uses[0].work_name == "Plane_1"
    assert "Plane_1" not in targets  # a feature is no target
    plain = Source.from_bytes("d.urscript", (FIXTURES / "plain_d.urscript").read_bytes())
    got = URSCRIPT.parse([plain], FrameTables())
    assert [t.name for t in got] == ["home", "inline@6", "inline@7"]
    assert got[1].configuration is not None and got[1].configuration.after == "home"


def test_an_unparseable_file_is_named_with_its_line_and_not_written(nominal: RobotModel) -> None:
    bad = (
        b"MODULE BAD\n  CONST robtarget p1:=[[1,2,3],[1,0,0,0],[0,0,0,0],\n  [9E9,9E9]];\n"
        b"ENDMODULE\n"
    )
    files = [("bad.mod", bad), ("notes_e.mod", (FIXTURES / "notes_e.mod").read_bytes())]
    run = filter_files(_identity(nominal), files)
    assert [e.file for e in run.errors] == ["bad.mod"]
    assert run.errors[0].line == 2 and "not a robtarget literal" in str(run.errors[0])
    assert "bad.mod" not in run.outputs and "notes_e.mod" in run.outputs
    assert run.exit_code == EXIT_BAD_INPUT


@pytest.mark.parametrize(
    ("name", "data", "message"),
    [
        ("prog.txt", b"MODULE X\nENDMODULE\n", "unknown program dialect"),
        ("prog.mod", b"def main():\n  movej([0,0,0,0,0,0])\nend\n", "the content is not rapid"),
        (
            "prog.mod",
            b"MODULE X\n  MoveL [[1,2,3],[1,0,0,0],[0,0,0,0],[9E9,9E9,9E9,9E9,9E9,9E9]"
            b", v10, fine, tool0;\n  VAR robtarget q:=[[1,2;\nENDMODULE\n",
            "prog.mod:3",
        ),
        (
            "prog.script",
            b"def main():\n  movel(p[0.1, 0.2, 0.3, 0, 0, 0], a=1\nend\n",
            "unclosed '(' of movel",
        ),
    ],
)
def test_bad_files_get_an_error_naming_them(
    nominal: RobotModel, name: str, data: bytes, message: str
) -> None:
    run = filter_files(_identity(nominal), [(name, data)])
    assert len(run.errors) == 1 and message in str(run.errors[0]), run.errors
    assert str(run.errors[0]).startswith(name)
    assert run.outputs == {} and run.exit_code == EXIT_BAD_INPUT


def test_dialect_by_extension_and_content() -> None:
    assert dialect_for(Source("a.MODX", "MODULE A\nENDMODULE\n", "utf-8")).name == "rapid"
    assert dialect_for(Source("a.urscript", "movel(p[0,0,0,0,0,0])\n", "utf-8")).name == "urscript"
    with pytest.raises(FilterInputError, match="unknown program dialect"):
        dialect_for(Source("a.csv", "x\n", "utf-8"))


def test_a_target_left_unchanged_is_named_and_counts(nominal: RobotModel) -> None:
    far = (
        b"MODULE FAR\n  CONST robtarget pFar:=[[9000,0,500],[0,0,1,0],[0,0,0,0],"
        b"[9E9,9E9,9E9,9E9,9E9,9E9]];\n  PROC main()\n    MoveL pFar, v100, fine, tool0;\n"
        b"  ENDPROC\nENDMODULE\n"
    )
    run = filter_files(_identity(nominal), [("far.mod", far)])
    assert run.outputs["far.mod"] == far
    (row,) = run.rows()
    assert row["name"] == "pFar" and row["status"] == "unreachable" and row["line"] == 2
    assert run.exit_code == EXIT_LEFT


def test_keep_joint_targets_and_only(nominal: RobotModel) -> None:
    cal = _identity(nominal)
    run = filter_files(cal, _fixture_files(), keep_joint_targets=True, only=["pEdge", "jHome"])
    status = {(r["file"], r["name"]): (r["status"], r["reason"]) for r in run.rows()}
    assert status[("cell_a.mod", "pEdge")] == ("corrected", "")
    assert status[("cell_a.mod", "jHome")] == (
        "skipped",
        "joint target kept (--keep-joint-targets)",
    )
    assert status[("cell_a.mod", "pApproach")] == ("skipped", "not selected (--only)")
    assert run.exit_code == 0  # left out on purpose: not counted
    run = filter_files(cal, _fixture_files(), keep_joint_targets=True)
    reason = {(r["file"], r["name"]): r["reason"] for r in run.rows()}
    assert reason[("cell_a.mod", "jHome")] == "joint target kept (--keep-joint-targets)"
    # A PolyScope q follows its pose: not a taught point, it still moves with it.
    assert reason[("polyscope_c.script", "Waypoint_1_q")] == ""


@pytest.mark.parametrize(
    ("text", "value", "decimals", "expected"),
    [
        ("12.5", 12.5000001, 3, "12.5"),  # equal at the written precision: kept
        ("12.5", 12.5004, 3, "12.5"),  # 12.500 is the same number
        ("12.5", 12.5006, 3, "12.501"),
        ("12.5", 12.6, 3, "12.600"),
        ("-.25", -0.2612345678, 6, "-.261235"),  # UR style without the leading zero
        ("7", 7.0, 0, "7"),
        ("-0.0000001", 0.00000001, 3, "0.0000000"),  # its own 7 decimals; never "-0"
        ("0.0", -0.0000001, 3, "0.0"),
    ],
)
def test_format_number(text: str, value: float, decimals: int, expected: str) -> None:
    assert format_number(Num("f", 0, len(text), text, float(text)), value, decimals) == expected


INLINE_QNEAR = """def p():
  set_tcp(p[0.0,-0.01,0.195,0.0,0.261799,0.0])
  movej(get_inverse_kin(p[1.111636171900, -.562373158417, .050303422831, -.434041488199, \
-2.389868508054, -.523936480595], qnear=[-0.5235987755982988, -0.7853981633974483, \
3.5779249665883754, 0.2617993877991494, 0.8726646259971648, -0.3490658503988659]), a=1.4, v=1.0)
end
""".replace("\\\n", "")


def test_an_inline_qnear_list_is_the_reference_and_follows(nominal: RobotModel) -> None:
    (p, q) = URSCRIPT.parse([Source("i.script", INLINE_QNEAR, "utf-8")], FrameTables())
    assert (p.name, q.name, q.follows) == ("inline@3", "qnear@3", "inline@3")
    assert p.configuration is not None and p.configuration.nearest_deg is not None
    run = filter_files(_identity(nominal), [("i.script", INLINE_QNEAR.encode())])
    assert [c.status for c in run.corrections] == ["corrected", "corrected"]
    assert run.outputs["i.script"] == INLINE_QNEAR.encode()


def test_a_correction_beyond_the_joint_limits_is_left_and_named(nominal: RobotModel) -> None:
    from filter_cells import rapid_module

    q = np.array([[179.995, -30.0, 190.0, 10.0, 50.0, -20.0]])
    text = rapid_module(nominal, q, np.eye(4), np.eye(4)).encode()
    table = nominal.dh_table.copy()
    table[0, 3] -= 0.02  # theta1: the calibrated robot needs q1 0.02 deg further
    cal = Calibration(
        nominal,
        RobotModel("cal", "dh", table, nominal.joint_limits_deg),
        None,
        np.zeros(0, dtype=int),
    )
    run = filter_files(cal, [("edge.mod", text)])
    (row,) = run.rows()
    assert row["status"] == "unreachable" and row["reason"].startswith(
        "outside the joint limits: J1=180.015"
    )
    assert run.outputs["edge.mod"] == text and run.exit_code == EXIT_LEFT
