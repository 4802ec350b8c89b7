"""cablecal filter, KUKA KRL: fixtures in KRL's real shapes, the emulated truth, bad input."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from filter_cells import Cell, make_cell, regular_poses, tool_frame, work_frame
from filter_olp import accuracy, krl_program, rms

from calib.filter.correct import Calibration, calibration_from_result
from calib.filter.run import EXIT_BAD_INPUT, EXIT_LEFT, filter_files
from calib.programs.krl.filter import DIALECT as KRL
from calib.programs.krl.filter import UNUSED, CartSite, configuration, turn_of
from calib.programs.rotations import frame, zyx_deg_to_matrix
from calib.programs.sites import Correction, FrameTables, Num, Source, Target

FIXTURES = Path(__file__).parent / "fixtures" / "programs" / "krl"
_NUMBER = re.compile(rb"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")
CORRECTED = {
    "XG1",
    "XG2",
    "XG3",
    "XG4",
    "XG5",
    "XG6",
    "XP1",
    "XP2",
    "XP3",
    "XP4",
    "XSEAM[1]",
    "XSEAM[2]",
    "XSEAM[3]",
    "XGLOBAL",
    "XNOST",
    "FAPP",
    "XHOME",
    "XPARK",
    "inline@63",
    "inline@101",
}


@pytest.fixture(scope="module")
def cell() -> Cell:
    return make_cell()


def _files() -> list[tuple[str, bytes]]:
    return [(p.name, p.read_bytes()) for p in sorted(FIXTURES.iterdir())]


def _identity(cell: Cell) -> Calibration:
    return Calibration(cell.nominal, cell.nominal, None, np.zeros(0, dtype=int))


def _status_turn(data: bytes) -> list[tuple[bytes, bytes]]:
    return re.findall(rb"(X\w*(?:\[\d\])?)=\{[^}]*?S ([^,}]+),T ([^,}]+)", data)


def test_calibration_equal_to_nominal_changes_no_byte(cell: Cell) -> None:
    run = filter_files(_identity(cell), _files())
    assert run.errors == []
    assert run.outputs == dict(_files())
    done = {r["name"] for r in run.rows() if r["status"] == "corrected"}
    assert done == CORRECTED  # corrected by nothing, not skipped
    assert all(c.shift_mm < 1e-6 for c in run.corrections if c.status == "corrected")


def test_a_real_calibration_changes_only_numbers_keeps_latin1_crlf_and_status(cell: Cell) -> None:
    files = dict(_files())
    run = filter_files(calibration_from_result(cell.result, cell.nominal), list(files.items()))
    assert run.errors == [] and run.exit_code == EXIT_LEFT
    for name, data in files.items():
        out = run.outputs[name]
        assert _NUMBER.sub(b"#", out) == _NUMBER.sub(b"#", data), name
        assert out.count(b"\r\n") == data.count(b"\r\n") == data.count(b"\n"), name
    for unchanged in ("$config.dat", "noop.src", "noop.dat"):
        assert run.outputs[unchanged] == files[unchanged]
    dat = run.outputs["weld_seam.dat"]
    assert "Schweißnaht".encode("latin-1") in dat  # still Latin-1
    assert dat != files["weld_seam.dat"]
    # S as it was; T where it was (it follows the joints, which keep their signs here).
    before, after = _status_turn(files["weld_seam.dat"]), _status_turn(dat)
    assert [(n, s) for n, s, _ in after] == [(n, s) for n, s, _ in before] and len(before) == 14
    # Targets left unchanged keep every byte of their line.
    for name in (b"XOFS", b"XTWO", b"XEXT", b"XUNUSED", b"XBAD", b"XMIS"):
        line = re.search(rb"E6POS " + name + rb"=[^\r]*", files["weld_seam.dat"])
        assert line is not None and line.group() in dat
    src = run.outputs["weld_seam.src"]
    assert re.search(rb"LIN \{Z [-\d.]+\}\r\n", src)  # the partial aggregate, untouched


def test_targets_frames_and_reasons(cell: Cell) -> None:
    sources = [Source.from_bytes(n, d) for n, d in _files()]
    targets = {t.name: t for t in KRL.parse(sources, FrameTables())}
    assert "F_OFS" not in targets  # a FRAME used only in an expression is no target
    assert targets["XP2"].line == 16  # declared without DECL
    use = targets["XP1"].uses[0]
    assert (use.file, use.line, use.tool_name, use.work_name) == (
        "weld_seam.src",
        32,
        "TOOL_DATA[1]",
        "BASE_DATA[2]",
    )
    gun = tool_frame(240.0, 15.0)  # what tests/fixtures was written with (to 3 and 4 decimals)
    assert use.tool is not None and use.work is not None
    np.testing.assert_allclose(use.tool, gun, atol=1e-3)
    np.testing.assert_allclose(use.work, work_frame(), atol=1e-3)
    assert [u.line for u in targets["XP3"].uses] == [48] == [u.line for u in targets["XP4"].uses]
    assert [u.tool_name for u in targets["XSEAM[2]"].uses] == ["TOOL_DATA[1]"]  # $TOOL=…
    cfg = targets["XP1"].configuration
    assert cfg is not None and cfg.text == "S 6 T 27"
    assert targets["XNOST"].configuration.after == "XGLOBAL"  # type: ignore[union-attr]
    assert targets["FAPP"].configuration.after == "XNOST"  # type: ignore[union-attr]
    inline = targets["inline@63"]
    assert inline.file == "weld_seam.src" and inline.configuration.text.startswith("S 'B")  # type: ignore[union-attr]
    # KSS 8.3 spline inline forms: the frames in the move's (or the SPLINE's) WITH clause.
    for name, line in (("XG1", 12), ("XG2", 15), ("XG4", 18), ("XG5", 22)):
        (u,) = targets[name].uses
        assert (u.file, u.line, u.tool_name, u.work_name, u.problem) == (
            "glue_bead.src",
            line,
            "TOOL_DATA[2]",
            "BASE_DATA[2]",
            "",
        )
    run = filter_files(_identity(cell), _files())
    reason = {r["name"]: r["reason"] for r in run.rows()}
    assert (
        "used with two tools/work objects (TOOL_DATA[1]/BASE_DATA[2] at line 65, "
        "TOOL_DATA[2]/BASE_DATA[2] at line 73)" in reason["XTWO"]
    )
    assert reason["XEXT"] == "line 81: FDAT FEXT: external TCP (IPO_FRAME #TCP) not supported"
    assert reason["XBAD"] == "line 90: the tool differs between the paths through the IF at line 85"
    assert (
        reason["XMIS"] == "line 97: the FOLD at line 92 says Tool[2] but TOOL_DATA[1] is in force"
    )
    assert "used in the expression 'XOFS:F_OFS'" in reason["XOFS"]
    assert reason["XUNUSED"] == UNUSED  # no FDAT of its own names its tool and base
    assert reason["inline@64"].startswith("X, Y, A, B, C not given")


def test_config_dat_names_are_global() -> None:
    cfg = (
        b"DEFDAT $CONFIG\r\n"
        b"DECL E6AXIS XPARK2={A1 10.0,A2 -50.0,A3 170.0,A4 0.0,A5 40.0,A6 0.0}\r\n"
    )
    src = b"DEF p( )\r\nPTP XPARK2\r\nEND\r\n"
    got = KRL.parse(
        [Source.from_bytes("$CONFIG.DAT", cfg + b"ENDDAT\r\n"), Source.from_bytes("p.src", src)],
        FrameTables(),
    )
    assert [(t.name, [u.line for u in t.uses]) for t in got] == [("XPARK2", [2])]


def test_branches_and_loops_merge_the_frames_of_their_paths() -> None:
    pos = "{X 900.0,Y 100.0,Z 800.0,A 0.0,B 90.0,C 0.0,S 2,T 10}"
    dat = "DEFDAT p\n" + "".join(f"DECL E6POS X{k}={pos}\n" for k in range(1, 6)) + "ENDDAT\n"
    src = (
        "DEF p( )\n$BASE=BASE_DATA[1]\n"
        "SWITCH N\nCASE 1\n$TOOL=TOOL_DATA[1]\nCASE 2\n$TOOL=TOOL_DATA[1]\n"
        "DEFAULT\n$TOOL=TOOL_DATA[1]\nENDSWITCH\nLIN X1\n"  # every path: tool 1
        "IF A THEN\n$TOOL=TOOL_DATA[2]\nENDIF\nLIN X2\n"  # IF without ELSE: unknown
        "$TOOL=TOOL_DATA[2]\nWHILE B\n  LIN X3\nENDWHILE\nLIN X4\n"  # no change: known
        "FOR I=1 TO 3\n  $BASE=BASE_DATA[I]\nENDFOR\nLIN X5\nEND\n"
    )
    cfg = (
        "DEFDAT $CONFIG\nTOOL_DATA[1]={X 0.0,Y 0.0,Z 100.0,A 0.0,B 0.0,C 0.0}\n"
        "TOOL_DATA[2]={X 0.0,Y 0.0,Z 200.0,A 0.0,B 0.0,C 0.0}\n"
        "BASE_DATA[1]={X 0.0,Y 0.0,Z 0.0,A 0.0,B 0.0,C 0.0}\nENDDAT\n"
    )
    files = [
        Source(n, text, "utf-8")
        for n, text in (("p.dat", dat), ("p.src", src), ("$config.dat", cfg))
    ]
    got = {t.name: t.uses[0] for t in KRL.parse(files, FrameTables())}
    assert (got["X1"].tool_name, got["X1"].problem) == ("TOOL_DATA[1]", "")
    assert got["X2"].problem == "the tool differs between the paths through the IF at line 12"
    assert (got["X3"].tool_name, got["X4"].tool_name, got["X4"].problem) == (
        "TOOL_DATA[2]",
        "TOOL_DATA[2]",
        "",
    )
    assert got["X5"].problem == "the base differs between the paths through the FOR at line 21"


def test_an_aggregate_over_several_lines_keeps_its_layout(cell: Cell) -> None:
    dat = (
        b"DEFDAT p\r\nDECL E6POS XP1={X 1200.0,Y 10.0,Z 900.0,\r\n"
        b"   A 0.0,B 90.0,C 0.0, S 2,T 2}\r\nENDDAT\r\n"
    )
    src = b"DEF p( )\r\n$TOOL=$NULLFRAME\r\n$BASE=$WORLD\r\nPTP XP1\r\nEND\r\n"
    files = [("p.dat", dat), ("p.src", src)]
    (target,) = KRL.parse([Source.from_bytes(n, d) for n, d in files], FrameTables())
    assert (target.line, target.uses[0].tool_name, target.uses[0].problem) == (2, "$NULLFRAME", "")
    np.testing.assert_allclose(target.pose[:3, 3], [1200, 10, 900])  # type: ignore[index]
    run = filter_files(calibration_from_result(cell.result, cell.nominal), files)
    assert run.corrections[0].status == "corrected"
    out = run.outputs["p.dat"]
    assert out != dat and _NUMBER.sub(b"#", out) == _NUMBER.sub(b"#", dat)


def test_an_unreachable_target_is_left_as_it_is_and_named(cell: Cell) -> None:
    dat = b"DEFDAT far\r\nDECL E6POS XFAR={X 9000.0,Y 0.0,Z 500.0,A 0.0,B 90.0,C 0.0}\r\nENDDAT\r\n"
    src = b"DEF far( )\r\nBAS(#TOOL,0)\r\nBAS(#BASE,0)\r\nPTP XFAR\r\nEND\r\n"
    run = filter_files(_identity(cell), [("far.dat", dat), ("far.src", src)])
    assert run.outputs == {"far.dat": dat, "far.src": src}
    (row,) = run.rows()
    assert (row["file"], row["line"], row["name"], row["status"]) == (
        "far.dat",
        2,
        "XFAR",
        "unreachable",
    )
    assert run.exit_code == EXIT_LEFT


def test_a_relative_move_leaves_its_offset_alone(cell: Cell) -> None:
    dat = (
        b"DEFDAT r\r\nDECL E6POS XDZ={X 0.0,Y 0.0,Z 20.0,A 0.0,B 0.0,C 0.0}\r\n"
        b"DECL E6AXIS XDA={A1 5.0,A2 0.0,A3 0.0,A4 0.0,A5 0.0,A6 0.0}\r\n"
        b"ENDDAT\r\n"
    )
    src = b"DEF r( )\r\nLIN_REL XDZ C_DIS\r\nPTP_REL XDA\r\nEND\r\n"
    run = filter_files(_identity(cell), [("r.dat", dat), ("r.src", src)])
    assert run.outputs == {"r.dat": dat, "r.src": src}
    assert [(r["name"], r["status"], r["reason"]) for r in run.rows()] == [
        ("XDZ", "skipped", "line 2: LIN_REL moves by it: an offset, not a pose"),
        ("XDA", "skipped", "line 3: PTP_REL moves by it: an offset, not a pose"),
    ]


def test_without_config_dat_the_frames_are_named(cell: Cell) -> None:
    files = [(n, d) for n, d in _files() if n != "$config.dat"]
    run = filter_files(_identity(cell), files)
    row = next(r for r in run.rows() if r["name"] == "XP1")
    assert row["status"] == "skipped"
    assert "TOOL_DATA[1] is not in the given files (give $config.dat)" in row["reason"]
    assert run.outputs["weld_seam.dat"] == dict(files)["weld_seam.dat"]


def test_accuracy_on_the_emulated_truth(cell: Cell) -> None:
    q = regular_poses(cell.nominal, 24, seed=21)
    tool, work = tool_frame(230.0), work_frame()
    text = krl_program(cell.nominal, q, tool, work)
    files = {k: v.encode("latin-1") for k, v in text.items()}
    run = filter_files(calibration_from_result(cell.result, cell.nominal), list(files.items()))
    assert run.errors == [] and run.exit_code == 0
    acc = accuracy(cell, KRL, files, run, FrameTables())
    n = acc["filtered_mm"].size
    assert n == 25  # 24 Cartesian targets and the home position
    assert np.all(acc["filtered_mm"] <= 1.5 * acc["floor_mm"] + 0.005)
    assert rms(acc["filtered_mm"]) <= 0.1 * rms(acc["unfiltered_mm"])
    assert np.all(acc["filtered_deg"] <= 1.5 * acc["floor_deg"] + 0.002)
    # The configuration: S as written, T from the corrected joints, the same branch.
    out = run.outputs["olp_path.dat"] + run.outputs["olp_path.src"]
    assert [s for _, s, _ in _status_turn(out)] == [
        s for _, s, _ in _status_turn(files["olp_path.dat"] + files["olp_path.src"])
    ]
    assert all(c.configuration_kept for c in run.corrections)
    by_name = {t.name: c for t, c in zip(run.targets, run.corrections, strict=True)}
    for name, _s, t in _status_turn(run.outputs["olp_path.dat"]):
        joints = by_name[name.decode()].joints_deg
        assert joints is not None and int(t) == turn_of(joints)


def test_status_and_turn_mapping() -> None:
    cfg = configuration(6, 35, "S 6 T 35")  # T 'B100011': A1, A2 and A6 negative
    assert cfg.joint_ranges_deg[0, 1] == 0.0 and cfg.joint_ranges_deg[2, 0] == 0.0
    assert cfg.joint_ranges_deg[5, 1] == 0.0 and cfg.joint_ranges_deg[4, 0] == 0.0
    assert (cfg.shoulder, cfg.elbow, cfg.wrist) == (1, 1, -1)
    assert (configuration(1, None, "").shoulder, configuration(1, None, "").elbow) == (-1, -1)
    assert turn_of(np.array([-1.0, 0.0, 5.0, -0.1, 2.0, -170.0])) == 0b101001


@pytest.mark.parametrize(
    ("old", "joints", "written"),
    [
        ("'B000010'", [-10, -30, 200, 5, 40, 10], False),  # A1 < 0: T would become 'B000011'
        ("'B10'", [10, 30, 200, -5, 40, -10], False),  # T would become 'B101000'
        ("2", [-10, -30, 200, 5, 40, 10], False),
        ("'B000010'", [10, -30, 200, 5, 40, 10], True),  # T stays 2
        ("2", [10, -30, 200, 5, 40, 10], True),
    ],
)
def test_a_correction_that_would_change_t_writes_nothing(
    old: str, joints: list[float], written: bool
) -> None:
    text = "X 1.0,Y 2.0,Z 3.0,A 0.0,B 0.0,C 0.0,T " + old
    nums = [
        Num("a.dat", m.start(1), m.end(1), m.group(1), float(m.group(1)))
        for m in re.finditer(r"[XYZABC] ([\d.]+)", text)
    ]
    start = text.index("T ") + 2
    turn = Num("a.dat", start, len(text), old, 2.0)
    target = Target(
        "a.dat", 1, "XP", "cartesian", pose=np.eye(4), site=CartSite(nums[:3], nums[3:], turn)
    )
    pose = frame(np.array([1.5, 2.0, 3.0]), zyx_deg_to_matrix(0.0, 0.0, 0.0))
    edits = KRL.render(target, Correction("corrected", pose=pose, joints_deg=np.array(joints)))
    # Never T itself; the X only when T stays.
    assert [(e.start, e.new) for e in edits] == ([(nums[0].start, "1.500")] if written else [])


@pytest.mark.parametrize(
    ("name", "data", "message"),
    [
        (
            "p.dat",
            b"DEFDAT p\r\nDECL E6POS XP1={X 1.0,Y 2.0,,Z 3.0}\r\nENDDAT\r\n",
            "p.dat:2: expected a component name, got ','",
        ),
        (
            "p.dat",
            b"DEFDAT p\nDECL E6POS XP1={X 1.0,X 2.0}\nENDDAT\n",
            "p.dat:2: component X given twice",
        ),
        (
            "p.dat",
            b"DEFDAT p\nDECL E6POS XP[2]\nXP[0]={X 1.0}\nENDDAT\n",
            "p.dat:3: array index [0] below 1",
        ),
        ("p.dat", b"DEFDAT p\nDECL E6POS XP1={X 1.0\nENDDAT\n", "p.dat:2: expected ',' or '}'"),
        ("p.src", b"; no routine here\nPTP XP1\n", "p.src:1: the content is not krl"),
        ("p.src", b"DEF p( )\n$TOOL=TOOL_DATA[1]\nLIN {X 1.0,Y 2 C_DIS\nEND\n", "p.src:3:"),
    ],
)
def test_bad_files_get_an_error_naming_file_and_line(
    cell: Cell, name: str, data: bytes, message: str
) -> None:
    run = filter_files(_identity(cell), [(name, data), ("noop.src", b"DEF noop( )\nEND\n")])
    assert len(run.errors) == 1 and str(run.errors[0]).startswith(message), run.errors
    assert name not in run.outputs and "noop.src" in run.outputs
    assert run.exit_code == EXIT_BAD_INPUT
