"""cablecal filter, Fanuc LS: fixtures in the ASCII export's shapes, the emulated truth, bad
input."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from filter_cells import Cell, make_cell, regular_poses, tool_frame, work_frame
from filter_olp import accuracy, frames_toml, ls_program, rms

from calib.filter.correct import Calibration, calibration_from_result
from calib.filter.run import EXIT_BAD_INPUT, EXIT_LEFT, filter_files
from calib.programs.fanuc.config import TURN_EDGE_DEG, TURN_JOINTS, configuration, turn_number
from calib.programs.fanuc.filter import DIALECT as LS
from calib.programs.fanuc.filter import INDIRECT_REGISTER_REASON, REGISTER_REASON
from calib.programs.sites import FrameTables, Source, parse_frames_toml

FIXTURES = Path(__file__).parent / "fixtures" / "programs" / "fanuc"
_NUMBER = re.compile(rb"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")
_CONFIG = re.compile(rb"CONFIG : '([^,']*),([^']*)'")


@pytest.fixture(scope="module")
def cell() -> Cell:
    return make_cell()


@pytest.fixture(scope="module")
def frames() -> FrameTables:
    return parse_frames_toml((FIXTURES / "frames.toml").read_text(), "frames.toml")


def _files() -> list[tuple[str, bytes]]:
    return [(p.name, p.read_bytes()) for p in sorted(FIXTURES.iterdir()) if p.suffix == ".LS"]


def _identity(cell: Cell) -> Calibration:
    return Calibration(cell.nominal, cell.nominal, None, np.zeros(0, dtype=int))


def _group2_and_registers(data: bytes) -> list[bytes]:
    gp2 = re.findall(rb"GP2:[^}]*", data)
    return gp2 + re.findall(rb"[^\n]*PR\[[^\n]*", data)


def test_calibration_equal_to_nominal_changes_no_byte(cell: Cell, frames: FrameTables) -> None:
    run = filter_files(_identity(cell), _files(), frames=frames)
    assert run.errors == []
    assert run.outputs == dict(_files())
    status = {r["name"]: r["status"] for r in run.rows()}
    assert status == {
        "P[1]": "corrected",
        "P[2]": "corrected",
        "P[3]": "corrected",
        "P[4]": "corrected",
        "P[5]": "skipped",
        "P[6]": "corrected",
        "P[8]": "skipped",
        "PR[1]": "skipped",
    }
    assert all(c.shift_mm < 1e-6 for c in run.corrections if c.status == "corrected")


def test_a_real_calibration_changes_only_position_numbers(cell: Cell, frames: FrameTables) -> None:
    files = dict(_files())
    run = filter_files(
        calibration_from_result(cell.result, cell.nominal), list(files.items()), frames=frames
    )
    assert run.errors == [] and run.exit_code == EXIT_LEFT
    out, data = run.outputs["PICK_PART.LS"], files["PICK_PART.LS"]
    assert out != data and run.outputs["GRIP_OPEN.LS"] == files["GRIP_OPEN.LS"]
    assert _NUMBER.sub(b"#", out) == _NUMBER.sub(b"#", data)
    assert out.count(b"\r\n") == data.count(b"\r\n") == data.count(b"\n")
    assert out.split(b"/POS")[0] == data.split(b"/POS")[0]  # /PROG, /ATTR, /MN untouched
    assert _group2_and_registers(out) == _group2_and_registers(data)  # GP2, PR[] untouched
    # CONFIG: the letters as they were; the turn numbers those of the corrected joints.
    assert [m[0] for m in _CONFIG.findall(out)] == [m[0] for m in _CONFIG.findall(data)]
    by_name = {t.name: c for t, c in zip(run.targets, run.corrections, strict=True)}
    for k, cfg in zip((1, 2, 3), _CONFIG.findall(out)[:3], strict=True):
        q = by_name[f"P[{k}]"].joints_deg
        assert q is not None
        assert [int(v) for v in cfg[1].split(b",")] == [turn_number(q[j]) for j in TURN_JOINTS]
    # Left unchanged: P[5] (UF 7 unknown) and P[8] (E1) keep every byte.
    for k in (5, 8):
        entry = re.search(rb"P\[%d\]\{.*?\};" % k, data, re.DOTALL)
        assert entry is not None and entry.group() in out


def test_frames_and_their_absence(cell: Cell, frames: FrameTables) -> None:
    sources = [Source.from_bytes(n, d) for n, d in _files()]
    targets = {t.name: t for t in LS.parse(sources, frames)}
    assert set(targets) == {"P[1]", "P[2]", "P[3]", "P[4]", "P[5]", "P[6]", "P[8]", "PR[1]"}
    use = targets["P[2]"].uses[0]
    assert (use.line, use.tool_name, use.work_name, use.problem) == (44, "UT:2", "UF:1", "")
    assert use.tool is not None and use.work is not None
    np.testing.assert_allclose(use.tool, tool_frame(185.0, -25.0), atol=1e-3)
    np.testing.assert_allclose(use.work, work_frame(), atol=1e-3)
    np.testing.assert_allclose(targets["P[6]"].uses[0].work, np.eye(4))  # UF 0
    assert targets["P[4]"].kind == "joint" and targets["P[4]"].uses == []
    cfg = targets["P[1]"].configuration
    assert cfg is not None and (cfg.wrist, cfg.elbow, cfg.shoulder) == (1, 1, 1)  # 'F U T'
    assert (targets["PR[1]"].line, targets["PR[1]"].problem) == (30, REGISTER_REASON)
    run = filter_files(_identity(cell), _files())  # no --frames
    reason = {r["name"]: r["reason"] for r in run.rows()}
    assert reason["P[1]"] == (
        "line 38: UF 1 is not in --frames ([uframe.1]); UT 2 is not in --frames ([utool.2])"
    )
    assert reason["P[6]"] == "line 74: UT 2 is not in --frames ([utool.2])"
    assert reason["P[8]"] == "GP1 has extended axes E1: not supported"
    status = {r["name"]: r["status"] for r in run.rows()}
    assert status["P[4]"] == "corrected"  # the joint form needs no frame


def test_an_unreachable_position_is_left_as_it_is_and_named(cell: Cell) -> None:
    far = _prog(_GOOD.replace(b"X = 1200.000", b"X = 9000.000"))
    run = filter_files(_identity(cell), [("FAR.LS", far)])
    assert run.outputs == {"FAR.LS": far}
    (row,) = run.rows()
    assert (row["line"], row["name"], row["status"]) == (6, "P[1]", "unreachable")
    assert run.exit_code == EXIT_LEFT


def test_an_incremental_or_offset_position_is_named(cell: Cell) -> None:
    second = _GOOD.replace(b"P[1]", b"P[2]")
    mn = (
        b"   1:L P[1] 100mm/sec FINE INC ;\n   2:  ! P[2] Offset in a remark only ;\n"
        b"   3:L P[2] 100mm/sec FINE Offset,PR[1] ;\n"
    )
    data = _prog(_GOOD + second).replace(b"   1:J P[1] 100% FINE ;\n", mn)
    run = filter_files(_identity(cell), [("OFS.LS", data)])
    assert run.outputs == {"OFS.LS": data}
    assert [(r["name"], r["status"], r["reason"]) for r in run.rows()] == [
        (
            "P[1]",
            "skipped",
            "line 4: moved to with INC: the robot does not go to the position itself",
        ),
        (
            "P[2]",
            "skipped",
            "line 6: moved to with Offset: the robot does not go to the position itself",
        ),
    ]


def test_an_indirect_position_register_is_named_never_a_traceback(cell: Cell) -> None:
    """``J PR[R[n]] …``: the register a data register names at run time (real ROBOGUIDE
    exports loop over ``PR[R[86]]`` with register speeds and ``CNT R[83]``, or name the data
    register ``PR[R[71:curr_pr]]``): left with its reason, the file unchanged."""
    mn = (
        b"   1:J P[1] 100% FINE ;\n   2:  R[86]=R[84]    ;\n"
        b"   3:J PR[R[86]] R[81]% CNT R[83] ACC R[82]    ;\n"
        b"   4:L PR[R[71:curr_pr]] 500mm/sec FINE    ;\n"
        b"   5:J PR[R[86]] R[81]% FINE ACC R[82]    ;\n"
    )
    data = _prog(_GOOD).replace(b"   1:J P[1] 100% FINE ;\n", mn)
    run = filter_files(_identity(cell), [("LOOP.LS", data)])
    assert run.outputs == {"LOOP.LS": data} and not run.errors
    rows = {r["name"]: (r["line"], r["status"], r["reason"]) for r in run.rows()}
    assert rows["PR[R[86]]"] == (6, "skipped", INDIRECT_REGISTER_REASON)
    assert rows["PR[R[71]]"] == (7, "skipped", INDIRECT_REGISTER_REASON)
    assert rows["P[1]"][1] == "corrected" and len(rows) == 3
    assert run.exit_code == EXIT_LEFT


def test_accuracy_on_the_emulated_truth(cell: Cell) -> None:
    q = regular_poses(cell.nominal, 24, seed=22)
    tool, work = tool_frame(195.0, 30.0), work_frame()
    frames = parse_frames_toml(frames_toml(tool, work))
    files = {"OLP_PATH.LS": ls_program(cell.nominal, q, tool, work).encode("ascii")}
    run = filter_files(
        calibration_from_result(cell.result, cell.nominal), list(files.items()), frames=frames
    )
    assert run.errors == [] and run.exit_code == 0
    acc = accuracy(cell, LS, files, run, frames)
    assert acc["filtered_mm"].size == 25  # 24 Cartesian positions and HOME in joint form
    assert np.all(acc["filtered_mm"] <= 1.5 * acc["floor_mm"] + 0.005)
    assert rms(acc["filtered_mm"]) <= 0.1 * rms(acc["unfiltered_mm"])
    assert np.all(acc["filtered_deg"] <= 1.5 * acc["floor_deg"] + 0.002)
    assert all(c.configuration_kept for c in run.corrections)


def test_configuration_and_turn_numbers() -> None:
    assert [turn_number(v) for v in (0.0, 179.9, 180.0, -180.0, -180.1, 540.0)] == [
        0,
        0,
        1,
        0,
        -1,
        2,
    ]
    cfg = configuration("F D B, 1, 0, -1", (1, 0, -1))
    assert (cfg.wrist, cfg.elbow, cfg.shoulder) == (1, 1, -1)  # F: J5 > 0; D behind: +1
    edge = np.array([-TURN_EDGE_DEG, -TURN_EDGE_DEG])  # read shifted down
    ranges = cfg.joint_ranges_deg
    windows = np.array([[180, 540], [-180, 180], [-540, -180]])
    np.testing.assert_allclose(ranges[[0, 3, 5]], windows + edge)
    assert np.all(np.isinf(ranges[[1, 2, 4]]))  # J1, J4, J6 carry the turns
    assert configuration("NUT, 0, 0, 0", (0, 0, 0)).wrist == -1


_GOOD = (
    b"P[1]{\n   GP1:\n\tUF : 0, UT : 0,\t\tCONFIG : 'N U T, 0, 0, 0',\n"
    b"\tX = 1200.000 mm,\tY = 0.000 mm,\tZ = 900.000 mm,\n"
    b"\tW = 180.000 deg,\tP = 0.000 deg,\tR = 0.000 deg\n};\n"
)


def _prog(pos: bytes, end: bytes = b"/END\n") -> bytes:
    """A program whose ``/POS`` section (from line 6) is ``pos``."""
    return b"/PROG  BAD\n/ATTR\n/MN\n   1:J P[1] 100% FINE ;\n/POS\n" + pos + end


@pytest.mark.parametrize(
    ("data", "message"),
    [
        (_prog(_GOOD.replace(b"\tW = 180.000 deg,", b"")), "BAD.LS:6: P[1]: GP1 has neither"),
        (_prog(_GOOD.replace(b"N U T", b"N X T")), "BAD.LS:6: P[1]: CONFIG 'N X T, 0, 0, 0'"),
        (_prog(_GOOD.replace(b"};\n", b"")), "BAD.LS:6: a position entry without its closing"),
        (_prog(_GOOD.replace(b"};", b"}")), "BAD.LS:11: expected '};' after a position"),
        (_prog(_GOOD + b"L P[2] 100mm/sec FINE ;\n"), "BAD.LS:12: expected P[n]{ in /POS"),
        (_prog(_GOOD.replace(b"UT : 0", b"UT : X")), "BAD.LS:6: P[1]: UF and UT must be numbers"),
        (_prog(_GOOD, end=b""), "BAD.LS:5: /POS without /END"),
        (b"! not a program\n", "BAD.LS:1: the content is not fanuc-ls"),
    ],
)
def test_bad_files_get_an_error_naming_file_and_line(cell: Cell, data: bytes, message: str) -> None:
    run = filter_files(_identity(cell), [("BAD.LS", data), *_files()])
    assert len(run.errors) == 1 and str(run.errors[0]).startswith(message), run.errors
    assert "BAD.LS" not in run.outputs and "GRIP_OPEN.LS" in run.outputs
    assert run.exit_code == EXIT_BAD_INPUT
