"""``cablecal filter`` as a person meets it: files written atomically to --out, the summary
file, the table at 80 columns, the exit codes, errors naming the file and line."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path
from typing import Any

import pytest
from filter_cells import Cell, make_cell
from typer.testing import CliRunner

from calib.export import model_to_toml
from calib.filter.run import EXIT_BAD_INPUT, EXIT_LEFT, EXIT_OK
from daemon.cli import app

FIXTURES = Path(__file__).parent / "fixtures" / "programs"
runner = CliRunner()


@pytest.fixture(scope="module")
def setup(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    cell: Cell = make_cell()
    d = tmp_path_factory.mktemp("filter-cli")
    (d / "result.json").write_text(json.dumps(cell.result))
    (d / "robot.toml").write_text(model_to_toml(cell.nominal))
    progs = d / "programs"
    shutil.copytree(FIXTURES, progs)
    return {"dir": d, "result": d / "result.json", "robot": d / "robot.toml", "progs": progs}


def _run(*args: Any) -> Any:
    return runner.invoke(app, ["filter", *map(str, args)], env={"COLUMNS": "80"})


def test_all_corrected_exit_0_files_and_summary(setup: dict[str, Path], tmp_path: Path) -> None:
    p = setup["progs"]
    out = tmp_path / "out"
    r = _run(
        setup["result"],
        p / "cell_a.mod",
        p / "polyscope_c.script",
        p / "notes_e.mod",
        "--robot",
        setup["robot"],
        "--out",
        out,
    )
    assert r.exit_code == EXIT_OK, r.output
    assert sorted(f.name for f in out.iterdir()) == [
        "cell_a.mod",
        "filter-summary.json",
        "notes_e.mod",
        "polyscope_c.script",
    ]
    assert (out / "notes_e.mod").read_bytes() == (p / "notes_e.mod").read_bytes()
    summary = json.loads((out / "filter-summary.json").read_text())
    assert summary["exit_code"] == 0 and summary["counts"]["corrected"] == 16
    row = next(t for t in summary["targets"] if t["name"] == "pEdge")
    assert row["file"] == "cell_a.mod" and row["line"] == 13 and row["status"] == "corrected"
    assert row["configuration_kept"] is True and row["tool"] == "tSpindle"
    assert 0 < row["sigma_at_tool_mm"] < 1 and row["shift_mm"] > 0.1
    # The old and new values as written, and the joints to check on the pendant.
    text = (p / "cell_a.mod").read_text()
    filtered = (out / "cell_a.mod").read_text()
    assert row["values"] and len(row["joints_deg"]) == 6 and len(row["nominal_joints_deg"]) == 6
    for v in row["values"]:
        assert v["old"] in text.splitlines()[v["line"] - 1]
        assert v["new"] in filtered.splitlines()[v["line"] - 1] and v["new"] != v["old"]
    lines = r.output.splitlines()
    assert max(len(line) for line in lines) <= 80
    big = max(summary["targets"], key=lambda t: t["shift_mm"])
    flat = " ".join(r.output.split())
    assert f"16 corrected: shift up to {big['shift_mm']:.3f} mm ({big['file']}:" in flat
    assert "16 targets: 16 corrected, 0 left unchanged" in r.output
    assert "Targets left unchanged" not in r.output  # no table when none is left


def test_targets_left_exit_3_and_are_named(setup: dict[str, Path], tmp_path: Path) -> None:
    p = setup["progs"]
    out = tmp_path / "out"
    r = _run(
        setup["result"],
        p / "station_b.prg",
        p / "tools_b.sys",
        "--robot",
        setup["robot"],
        "--out",
        out,
    )
    assert r.exit_code == EXIT_LEFT, r.output
    table = [line.strip("│ ") for line in r.output.splitlines()]
    # One row per reason, its count and its targets; the unused point not counted as left.
    assert any(re.match(r"1 │ skipped: used with two tools/work objects; .*pB3", t) for t in table)
    assert any(re.match(r"1 │ skipped: wobjdata wMissing is not declared .*pB4", t) for t in table)
    assert any(re.match(r"1 │ unused: not used by any move .*pB5", t) for t in table)
    assert "6 targets: 3 corrected, 2 left unchanged, 1 not used by any move" in r.output
    assert "pB4: skipped: line 26" not in r.output  # the full reasons with --verbose
    assert (out / "station_b.prg").read_bytes() != (p / "station_b.prg").read_bytes()
    assert sorted(f.name for f in tmp_path.iterdir()) == ["out"]  # no temporary left
    summary = json.loads((out / "filter-summary.json").read_text())
    assert summary["counts"]["left"] == 2 and summary["counts"]["unused"] == 1
    assert all(t["reason"] for t in summary["targets"] if t["status"] != "corrected")
    verbose = _run(
        setup["result"],
        p / "station_b.prg",
        p / "tools_b.sys",
        "--robot",
        setup["robot"],
        "--out",
        out,
        "--verbose",
    )
    assert verbose.exit_code == EXIT_LEFT
    text = " ".join(verbose.output.split())
    assert "station_b.prg:14 pB3: skipped: used with two tools/work objects" in text
    assert "station_b.prg:15 pB4: skipped: line 26: wobjdata wMissing is not declared" in text
    assert "station_b.prg:16 pB5: skipped: not used by any move" in text
    assert max(len(line) for line in verbose.output.splitlines()) <= 80


def test_an_unparseable_file_exit_2_named_and_not_written(
    setup: dict[str, Path], tmp_path: Path
) -> None:
    bad = tmp_path / "bad.mod"
    bad.write_bytes(
        b"MODULE B\n  PROC p()\n    MoveL [[1,2,3],[1,0,0,0]], v1, fine, tool0;\n"
        b"  ENDPROC\nENDMODULE\n"
    )
    out = tmp_path / "out"
    r = _run(
        setup["result"], bad, setup["progs"] / "cell_a.mod", "--robot", setup["robot"], "--out", out
    )
    assert r.exit_code == EXIT_BAD_INPUT
    assert "bad.mod:3: inline value is neither a robtarget nor a jointtarget" in r.output
    assert not (out / "bad.mod").exists() and (out / "cell_a.mod").exists()


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--frames", "{dir}/missing.toml"], "--frames"),
        (["--frames", "{dir}/bad_frames.toml"], "[utool.1]: needs exactly xyz_mm and wpr_deg"),
        (["--robot", "no-such-robot"], "--robot"),
    ],
)
def test_bad_options_exit_2(
    setup: dict[str, Path], tmp_path: Path, extra: list[str], message: str
) -> None:
    (setup["dir"] / "bad_frames.toml").write_text("[utool.1]\nxyz_mm = [0, 0, 200]\n")
    args = [a.format(dir=setup["dir"]) for a in extra]
    if "--robot" not in args:
        args += ["--robot", str(setup["robot"])]
    r = _run(setup["result"], setup["progs"] / "cell_a.mod", *args, "--out", tmp_path / "o")
    assert r.exit_code == EXIT_BAD_INPUT and message in " ".join(r.output.split()), r.output
    assert not (tmp_path / "o").exists()


def test_out_must_not_hold_the_inputs(setup: dict[str, Path]) -> None:
    r = _run(
        setup["result"],
        setup["progs"] / "cell_a.mod",
        "--robot",
        setup["robot"],
        "--out",
        setup["progs"],
    )
    assert r.exit_code == EXIT_BAD_INPUT and "holds the input" in r.output


def test_help_lists_the_exit_codes() -> None:
    r = runner.invoke(app, ["filter", "--help"], env={"COLUMNS": "80"})
    lines = [line.strip(" │") for line in r.output.splitlines()]
    codes = (
        f"{EXIT_OK} every target corrected",
        f"{EXIT_LEFT} some targets left unchanged (named in filter-summary.json)",
        f"{EXIT_BAD_INPUT} bad input (a file that cannot be read is not written)",
    )
    for code in codes:
        assert code in lines, r.output
