"""``cablecal filter``: nothing silently wrong, nothing silently nothing (issue 34 items 5, 6).

Unknown ``--only`` names, a file whose content is another dialect's, an empty file and a
result of another arm give exit 2 naming them; a result naming another robot a warning;
``--help`` shows every bracket; the output keeps the input's mode; ``--out`` is replaced as
one set; a long program's left targets are a few lines grouped by reason, at 80 columns.
"""

from __future__ import annotations

import json
import os
import shutil
import stat
from pathlib import Path
from typing import Any

import pytest
from filter_cells import Cell, make_cell, rapid_module, regular_poses, tool_frame, work_frame
from typer.testing import CliRunner

from calib.export import model_to_toml
from calib.filter import run as run_module
from calib.filter.correct import calibration_from_result
from calib.filter.run import (
    EXIT_BAD_INPUT,
    EXIT_LEFT,
    EXIT_OK,
    _with_reasons,
    filter_files,
    reason_group,
    summary_text,
)
from calib.programs.dialects import dialect_for
from calib.programs.sites import Correction, FrameTables, Source
from daemon.cli import app, filter_out
from daemon.datafiles import load_robot

FIXTURES = Path(__file__).parent / "fixtures" / "programs"
runner = CliRunner()


@pytest.fixture(scope="module")
def cell() -> Cell:
    return make_cell()


@pytest.fixture(scope="module")
def setup(cell: Cell, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("filter-checks")
    (d / "result.json").write_text(json.dumps(cell.result))
    (d / "robot.toml").write_text(model_to_toml(cell.nominal))
    return {"result": d / "result.json", "robot": d / "robot.toml", "dir": d}


def _run(setup: dict[str, Path], *args: Any, result: Path | None = None) -> Any:
    argv = [str(result or setup["result"]), *map(str, args), "--robot", str(setup["robot"])]
    return runner.invoke(app, ["filter", *argv], env={"COLUMNS": "80"})


def _flat(text: str) -> str:
    return " ".join(text.split())


def test_unknown_only_names_exit_2_naming_them_and_nothing_written(
    setup: dict[str, Path], tmp_path: Path
) -> None:
    out = tmp_path / "out"
    r = _run(setup, FIXTURES / "cell_a.mod", "--only", "pEdge,NoSuchName,nope2", "--out", out)
    assert r.exit_code == EXIT_BAD_INPUT, r.output
    assert "--only: no target named NoSuchName, nope2 in the given files" in _flat(r.output)
    assert not out.exists()
    ok = _run(setup, FIXTURES / "cell_a.mod", "--only", "PEDGE", "--out", out)  # any case
    assert ok.exit_code == EXIT_OK, ok.output


@pytest.mark.parametrize(
    ("source", "name", "message"),
    [
        (
            "fanuc/GRIP_OPEN.LS",
            "GRIP_OPEN.script",
            "GRIP_OPEN.script:2: the content is not urscript (extension .script): it looks "
            "like a Fanuc LS program",
        ),
        (
            "cell_a.mod",
            "cell_a.src",
            "cell_a.src:6: the content is not krl (extension .src): it looks like an ABB "
            "RAPID module (a MODULE statement); give it its own extension (.mod,",
        ),
        (
            "krl/glue_bead.src",
            "glue_bead.mod",
            "glue_bead.mod:3: the content is not rapid (extension .mod): it looks like a KUKA "
            "KRL program",
        ),
        (
            "polyscope_c.script",
            "polyscope_c.ls",
            "polyscope_c.ls:1: the content is not fanuc-ls (extension .ls): it looks like a "
            "URScript program",
        ),
    ],
)
def test_content_of_another_dialect_exit_2_saying_what_it_looks_like(
    setup: dict[str, Path], tmp_path: Path, source: str, name: str, message: str
) -> None:
    f = tmp_path / name
    shutil.copyfile(FIXTURES / source, f)
    out = tmp_path / "out"
    r = _run(setup, f, FIXTURES / "cell_a.mod", "--out", out)
    assert r.exit_code == EXIT_BAD_INPUT, r.output
    assert message in _flat(r.output)
    assert not (out / name).exists() and (out / "cell_a.mod").exists()


@pytest.mark.parametrize(("body", "what"), [(b"", "0 bytes"), (b"\r\n  \r\n", "only white space")])
def test_an_empty_file_exit_2_naming_it(
    setup: dict[str, Path], tmp_path: Path, body: bytes, what: str
) -> None:
    f = tmp_path / "EMPTY.LS"
    f.write_bytes(body)
    r = _run(setup, f, "--out", tmp_path / "out")
    assert r.exit_code == EXIT_BAD_INPUT, r.output
    assert f"EMPTY.LS: empty file ({what}): no program to filter" in _flat(r.output)


def test_a_result_of_another_robot_warns_and_another_arm_exit_2(
    setup: dict[str, Path], cell: Cell, tmp_path: Path
) -> None:
    renamed = dict(cell.result, robot="abb-irb120")
    p = tmp_path / "renamed.json"
    p.write_text(json.dumps(renamed))
    out = tmp_path / "out"
    r = _run(setup, FIXTURES / "cell_a.mod", "--out", out, result=p)
    assert r.exit_code == EXIT_OK, r.output
    assert (
        f"warning: {p}: the result is of robot 'abb-irb120', the nominal model is "
        f"'{cell.nominal.name}'" in _flat(r.output)
    )
    assert "abb-irb120" in json.loads((out / "filter-summary.json").read_text())["warning"]
    # Another arm: joint 2's a 50 mm longer than a calibration moves it.
    other = json.loads(json.dumps(cell.result))
    other["dh"][1]["a_mm"] += 50.0
    p2 = tmp_path / "other.json"
    p2.write_text(json.dumps(other))
    r2 = _run(setup, FIXTURES / "cell_a.mod", "--out", tmp_path / "o2", result=p2)
    assert r2.exit_code == EXIT_BAD_INPUT, r2.output
    assert "is not of the nominal model" in r2.output and "joint 2 a_mm" in _flat(r2.output)
    assert not (tmp_path / "o2").exists()
    # A table of another size (five joints): exit 2 naming the field, nothing written.
    short = json.loads(json.dumps(cell.result))
    short["dh"] = short["dh"][:5]
    p3 = tmp_path / "short.json"
    p3.write_text(json.dumps(short))
    r3 = _run(setup, FIXTURES / "cell_a.mod", "--out", tmp_path / "o3", result=p3)
    assert r3.exit_code == EXIT_BAD_INPUT, r3.output
    assert "dh: expected a list of six joint rows" in _flat(r3.output)
    assert not (tmp_path / "o3").exists()


def test_help_renders_every_bracket_at_80_columns() -> None:
    r = runner.invoke(app, ["filter", "--help"], env={"COLUMNS": "80", "NO_COLOR": "1"})
    assert r.exit_code == 0
    assert max(len(line) for line in r.output.splitlines()) <= 80
    text = _flat(r.output.replace("│", " "))
    assert "TOML of [uframe.N] / [utool.N] (xyz_mm, wpr_deg)." in text
    assert "external_axes = 0 in its [controller] table" in text
    assert "--verbose" in text


@pytest.mark.parametrize("mode", [0o644, 0o640, 0o600])
def test_output_files_keep_the_input_mode(
    setup: dict[str, Path], tmp_path: Path, mode: int
) -> None:
    f = tmp_path / "cell_a.mod"
    shutil.copyfile(FIXTURES / "cell_a.mod", f)
    os.chmod(f, mode)
    out = tmp_path / "out"
    assert _run(setup, f, "--out", out).exit_code == EXIT_OK
    assert stat.S_IMODE((out / "cell_a.mod").stat().st_mode) == mode
    summary_mode = stat.S_IMODE((out / "filter-summary.json").stat().st_mode)
    assert summary_mode == filter_out.default_file_mode()


def test_out_is_replaced_as_one_set(setup: dict[str, Path], tmp_path: Path) -> None:
    out = tmp_path / "out"
    r1 = _run(setup, FIXTURES / "cell_a.mod", FIXTURES / "notes_e.mod", "--out", out)
    assert r1.exit_code == EXIT_OK
    r2 = _run(setup, FIXTURES / "polyscope_c.script", "--out", out)
    assert r2.exit_code == EXIT_OK, r2.output
    # The previous set is gone whole: no file of it beside the new summary.
    assert sorted(f.name for f in out.iterdir()) == ["filter-summary.json", "polyscope_c.script"]
    assert sorted(f.name for f in tmp_path.iterdir()) == ["out"]
    # A directory of other files is never replaced.
    other = tmp_path / "mine"
    other.mkdir()
    (other / "keep.txt").write_text("mine")
    r3 = _run(setup, FIXTURES / "cell_a.mod", "--out", other)
    assert r3.exit_code == EXIT_BAD_INPUT
    assert "holds other files and no filter-summary.json" in _flat(r3.output)
    assert [f.name for f in other.iterdir()] == ["keep.txt"]


def test_an_interrupted_write_leaves_the_previous_set_and_no_temporary(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    out = tmp_path / "out"
    filter_out.write_set(out, {"a.mod": (b"old", 0o644), "s.json": (b"{}", 0o644)}, "s.json")
    calls = {"n": 0}
    real = os.fsync

    def fsync(fd: int) -> None:
        calls["n"] += 1
        if calls["n"] == 2:  # the second file: killed half-way through the set
            raise KeyboardInterrupt
        real(fd)

    monkeypatch.setattr(os, "fsync", fsync)
    with pytest.raises(KeyboardInterrupt):
        filter_out.write_set(
            out,
            {"a.mod": (b"new", 0o644), "b.mod": (b"x", 0o644), "s.json": (b"{}", 0o644)},
            "s.json",
        )
    monkeypatch.undo()
    assert sorted(f.name for f in tmp_path.iterdir()) == ["out"]
    assert sorted(f.name for f in out.iterdir()) == ["a.mod", "s.json"]
    assert (out / "a.mod").read_bytes() == b"old"


def test_a_killed_runs_temporary_is_removed_by_the_next(tmp_path: Path) -> None:
    out = tmp_path / "out"
    # What SIGKILL leaves: a temporary directory of a process that is gone.
    dead = 2**22 + 12345  # above Linux's default pid_max of 4194304: no such process
    stale = tmp_path / f".out{filter_out.TMP_TAG}{dead}-abc"
    stale.mkdir()
    (stale / "a.mod").write_bytes(b"half")
    mine = tmp_path / f".out{filter_out.TMP_TAG}{os.getpid()}-live"
    mine.mkdir()  # a live process's: left alone
    filter_out.write_set(out, {"s.json": (b"{}", 0o644)}, "s.json")
    assert not stale.exists() and mine.exists()
    assert [f.name for f in out.iterdir()] == ["s.json"]


def test_a_long_program_left_targets_are_grouped_at_80_columns(
    setup: dict[str, Path], cell: Cell, tmp_path: Path
) -> None:
    q = regular_poses(cell.nominal, 300, seed=3)
    text = rapid_module(cell.nominal, q, tool_frame(220.0), work_frame())
    lines = text.splitlines(keepends=True)
    # Every other move with a work object the module does not declare: 150 left.
    moves = [k for k, line in enumerate(lines) if "\\WObj:=wOlp" in line]
    for k in moves[::2]:
        lines[k] = lines[k].replace("\\WObj:=wOlp", "\\WObj:=wGone")
    f = tmp_path / "LONG.mod"
    f.write_text("".join(lines))
    out = tmp_path / "out"
    r = _run(setup, f, "--out", out)
    assert r.exit_code == EXIT_LEFT, r.output
    out_lines = r.output.splitlines()
    assert max(len(line) for line in out_lines) <= 80
    assert len(out_lines) < 30  # not a line per target
    flat = _flat(r.output.replace("│", " "))
    assert "150 skipped: wobjdata wGone is not declared" in flat
    assert "… 147 more" in flat
    assert "300 targets: 150 corrected, 150 left unchanged" in flat
    summary = json.loads((out / "filter-summary.json").read_text())
    groups = summary["left_by_reason"]
    assert list(groups.values()) == [150] and next(iter(groups)).startswith("skipped: wobjdata")
    rv = _run(setup, f, "--out", out, "-v")
    assert len(rv.output.splitlines()) > 150  # every left target, with --verbose
    assert max(len(line) for line in rv.output.splitlines()) <= 80


def test_reasons_group_without_their_figures_and_none_is_empty() -> None:
    a = reason_group("unreachable", "outside the joint limits: J3=121.402 (limit 120)")
    b = reason_group("unreachable", "outside the joint limits: J3=-130.5 (limit -120)")
    c = reason_group("unreachable", "outside the joint limits: J5=121.402 (limit 120)")
    assert a == b != c
    assert reason_group("skipped", "line 12: wobjdata w1 is not declared") == reason_group(
        "skipped", "line 40: wobjdata w1 is not declared"
    )
    assert reason_group("skipped", "not selected (--only)") == "skipped: not selected (--only)"
    unused = "not used by any move in the given files: its tool and work object are unknown"
    assert reason_group("skipped", unused).startswith("unused: ")
    src = Source.from_bytes("x.mod", (FIXTURES / "cell_a.mod").read_bytes())
    d = dialect_for(src)
    t = d.parse([src], FrameTables())[0]
    fixed = _with_reasons([Correction("skipped", " "), Correction("corrected")], [(d, t), (d, t)])
    assert "without a reason (a bug of the filter's rapid dialect" in fixed[0].reason
    assert fixed[1].reason == ""


def test_summary_text_is_the_summary_one_target_a_line(setup: dict[str, Path]) -> None:
    cell_files = [("cell_a.mod", (FIXTURES / "cell_a.mod").read_bytes())]
    result = json.loads(setup["result"].read_text())
    nominal = load_robot(str(setup["robot"]))
    run = filter_files(calibration_from_result(result, nominal), cell_files)
    text = summary_text(run.summary(targets=False), run.iter_rows())
    assert json.loads(text) == run.summary()
    lines = text.splitlines()
    rows = [line for line in lines if line.startswith('    {"file": ')]
    assert len(rows) == len(run.targets)  # one line per target
    assert json.loads(summary_text({"a": 1}, [])) == {"a": 1, "targets": []}


def test_batches_keep_targets_that_refer_to_each_other_together(
    setup: dict[str, Path], cell: Cell, monkeypatch: pytest.MonkeyPatch
) -> None:
    names = ["cell_a.mod", "polyscope_c.script", "plain_d.urscript", "station_b.prg"]
    files = [(n, (FIXTURES / n).read_bytes()) for n in [*names, "tools_b.sys"]]
    cal = calibration_from_result(cell.result, cell.nominal)
    whole = filter_files(cal, files)
    monkeypatch.setattr(run_module, "CORRECT_BATCH", 3)
    parts = run_module.batches(whole.targets)
    assert len(parts) > 3
    assert sorted(i for b in parts for i in b) == list(range(len(whole.targets)))
    for b in parts:
        assert b == sorted(b)
        keys = {(whole.targets[i].file, whole.targets[i].name) for i in b}
        for i in b:  # what a target refers to is in its batch
            t = whole.targets[i]
            after = t.configuration.after if t.configuration is not None else None
            for other in (t.follows, after):
                if other is not None and any(
                    (u.file, u.name) == (t.file, other) for u in whole.targets
                ):
                    assert (t.file, other) in keys, (t.name, other)
    batched = filter_files(cal, files)
    assert batched.outputs == whole.outputs
    assert [(c.status, c.reason) for c in batched.corrections] == [
        (c.status, c.reason) for c in whole.corrections
    ]


def test_a_corrected_rows_joints_are_the_controllers_own_at_the_new_values(
    setup: dict[str, Path], cell: Cell
) -> None:
    """Per corrected target the summary gives the old and new text, the joints the controller
    reaches the new pose at (on the branch its configuration says: the confdata written in
    the output is theirs), the shift and the σ at its tool."""

    import numpy as np

    from calib.filter.branches import branch_signs
    from calib.filter.kin import flange_frames
    from calib.programs.rapid.filter import QUADRANT_EDGE_DEG, RobSite

    files = [("cell_a.mod", (FIXTURES / "cell_a.mod").read_bytes())]
    run = filter_files(calibration_from_result(cell.result, cell.nominal), files)
    rows = {r["name"]: r for r in run.rows()}
    out_src = Source.from_bytes("cell_a.mod", run.outputs["cell_a.mod"])
    again = {t.name: t for t in dialect_for(out_src).parse([out_src], FrameTables())}
    # The run lets go of a written target's numbers (its site): the input's, read again.
    in_src = Source.from_bytes("cell_a.mod", files[0][1])
    before = {t.name: t for t in dialect_for(in_src).parse([in_src], FrameTables())}
    checked = 0
    for t, c in zip(run.targets, run.corrections, strict=True):
        if c.status != "corrected" or t.kind != "cartesian" or not c.shift_mm > 0.05:
            continue
        row = rows[t.name]
        q = np.array(row["joints_deg"])
        use = t.uses[0]
        assert use.tool is not None and use.work is not None and c.pose is not None
        # FK of the row's joints (4 decimals) is the new pose, in its work object and tool.
        at = flange_frames(cell.nominal, q[None])[0] @ use.tool
        np.testing.assert_allclose(at[:3, 3], (use.work @ c.pose)[:3, 3], atol=0.01)
        # The same branch as the original target's nominal solution.
        s_new = np.stack(branch_signs(cell.nominal, q[None]), axis=1)
        s_old = np.stack(branch_signs(cell.nominal, np.array([row["nominal_joints_deg"]])), axis=1)
        assert np.array_equal(s_new, s_old)
        # The quadrants the output file holds are the input's, and the row's joints lie in
        # them (within the edge tolerance of a quadrant line).
        site = again[t.name].site
        assert isinstance(site, RobSite)
        written = [int(n.value) for n in site.conf[:3]]
        old_site = before[t.name].site
        assert isinstance(old_site, RobSite)
        assert written == [int(n.value) for n in old_site.conf[:3]]
        for cf, j in zip(written, (0, 3, 5), strict=True):
            assert 90.0 * cf - QUADRANT_EDGE_DEG <= q[j] < 90.0 * cf + 90.0 + QUADRANT_EDGE_DEG
        assert row["values"] and all(v["old"] != v["new"] for v in row["values"])
        assert row["shift_mm"] > 0 and row["sigma_at_tool_mm"] is not None
        checked += 1
    assert checked >= 5
