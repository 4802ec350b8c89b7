"""``cablecal compensate``, ``export`` and ``verify`` on a synthetic cell: their files, their
80-column tables, and errors that name the file, row or option."""

from __future__ import annotations

import csv
import io
import json
import tomllib
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rich.console import Console
from typer.testing import CliRunner

from calib.dataset import make_samples
from calib.identify import IdentifyOptions, identify
from calib.models import builtin_model, parse_model_text
from calib.synthetic import TrueCell, make_true_cell, noisy_lengths, random_poses_deg
from daemon.cli import app

NOISE_MM = 0.03
runner = CliRunner()


def _csv(q: np.ndarray, lengths: np.ndarray | None = None) -> str:
    cols = [f"q{j}" for j in range(1, 7)] + (["L"] if lengths is not None else [])
    lines = [",".join(cols)]
    for i, row in enumerate(q):
        vals = [f"{v:.6f}" for v in row] + ([f"{lengths[i]:.4f}"] if lengths is not None else [])
        lines.append(",".join(vals))
    return "\n".join(lines) + "\n"


@pytest.fixture(scope="module")
def cell_and_result(tmp_path_factory: pytest.TempPathFactory) -> tuple[TrueCell, Path, Path]:
    nominal = builtin_model("hsr-jr680")
    cell = make_true_cell(nominal)
    rng = np.random.default_rng(7)
    q = random_poses_deg(cell, 80, rng)
    samples = make_samples(q, noisy_lengths(cell, q, rng, noise_mm=NOISE_MM))
    result = identify(nominal, samples, IdentifyOptions(method="lm", test_fraction=0.2)).to_json()
    d = tmp_path_factory.mktemp("apply")
    path = d / "result.json"
    path.write_text(json.dumps(result), encoding="utf-8")
    q2 = random_poses_deg(cell, 30, rng)
    data = d / "check.csv"
    data.write_text(_csv(q2, noisy_lengths(cell, q2, rng, noise_mm=NOISE_MM)), encoding="utf-8")
    return cell, path, data


def _run(*args: str) -> Any:
    return runner.invoke(app, list(args), env={"COLUMNS": "80"})


def _wide_lines(text: str) -> list[str]:
    return [line for line in text.splitlines() if len(line) > 80]


def test_compensate_writes_corrected_joints(
    cell_and_result: tuple[TrueCell, Path, Path], tmp_path: Path
) -> None:
    cell, result, _ = cell_and_result
    q = random_poses_deg(cell, 12, np.random.default_rng(3))
    targets = tmp_path / "program.csv"
    targets.write_text(_csv(q), encoding="utf-8")
    out = tmp_path / "corrected.csv"
    r = _run("compensate", str(result), str(targets), "--out", str(out), "--tool-mm", "0,0,50")
    assert r.exit_code == 0, r.output
    rows = list(csv.DictReader(io.StringIO(out.read_text())))
    assert len(rows) == 12
    corrected = np.array([[float(row[f"q{j}"]) for j in range(1, 7)] for row in rows])
    nominal = np.array([[float(row[f"q{j}_nominal"]) for j in range(1, 7)] for row in rows])
    np.testing.assert_allclose(nominal, q, atol=5e-4 + 1e-9)  # the output rounds to 0.001 deg
    assert 1e-3 < np.abs(corrected - q).max() < 5.0  # corrected, and by a plausible amount
    assert max(float(row["residual_mm"]) for row in rows) < 0.01
    assert "targets" in r.output and "base z axis" in r.output  # summary and the note
    assert not _wide_lines(r.output)


def test_compensate_errors_name_the_file_row_and_option(
    cell_and_result: tuple[TrueCell, Path, Path], tmp_path: Path
) -> None:
    _, result, _ = cell_and_result
    bad = tmp_path / "bad.csv"
    bad.write_text("q1,q2,q3,q4,q5,q6\n0,0,0,0,0,0\n0,x,0,0,0,0\n", encoding="utf-8")
    r = _run("compensate", str(result), str(bad), "--out", str(tmp_path / "o.csv"))
    assert r.exit_code == 2 and "bad.csv" in r.output and "line 3" in r.output
    assert "'q2'" in r.output
    r = _run("compensate", str(result), str(bad), "--out", "o.csv", "--tool-mm", "1,2")
    assert r.exit_code == 2 and "--tool-mm" in r.output
    r = _run("compensate", str(result), str(bad), "--out", "o.csv", "--mode", "joint")
    assert r.exit_code == 2 and "--mode" in r.output
    cart = tmp_path / "cart.csv"
    cart.write_text("x,y,z\n500,0,600\n", encoding="utf-8")
    r = _run("compensate", str(result), str(cart), "--out", str(tmp_path / "o.csv"))
    assert r.exit_code == 2 and "--seed-deg" in r.output
    broken = tmp_path / "broken.json"
    broken.write_text("{not json", encoding="utf-8")
    r = _run("compensate", str(broken), str(cart), "--out", "o.csv")
    assert r.exit_code == 2 and "broken.json" in r.output


@pytest.mark.parametrize("fmt", ["toml", "json", "urdf"])
def test_export_writes_each_format(
    cell_and_result: tuple[TrueCell, Path, Path], tmp_path: Path, fmt: str
) -> None:
    _, result, _ = cell_and_result
    out = tmp_path / f"model.{fmt}"
    r = _run("export", str(result), "--format", fmt, "--out", str(out))
    assert r.exit_code == 0, r.output
    text = out.read_text()
    res = json.loads(result.read_text())
    if fmt == "urdf":
        assert text.lstrip().startswith("<") and "joint_6" in text
        return
    model = parse_model_text(text, fmt)
    assert model.dh_table[1, 1] == pytest.approx(res["dh"][1]["a_mm"], abs=1e-9)  # a2 [mm]
    if fmt == "toml":
        assert tomllib.loads(text)["name"].endswith("calibrated")


def test_export_rejects_an_unknown_format(cell_and_result: tuple[TrueCell, Path, Path]) -> None:
    _, result, _ = cell_and_result
    r = _run("export", str(result), "--format", "step", "--out", "x.step")
    assert r.exit_code == 2 and "--format" in r.output and "urdf" in r.output


def test_verify_prints_figures_and_writes_residuals(
    cell_and_result: tuple[TrueCell, Path, Path], tmp_path: Path
) -> None:
    _, result, data = cell_and_result
    out = tmp_path / "residuals.csv"
    r = _run("verify", str(result), str(data), "--out", str(out))
    assert r.exit_code == 0, r.output
    rows = list(csv.DictReader(io.StringIO(out.read_text())))
    assert len(rows) == 30
    res = np.array([float(row["residual_mm"]) for row in rows])
    rmse = float(np.sqrt(np.mean(res**2)))
    assert 0.5 * NOISE_MM < rmse < 2.0 * NOISE_MM
    assert f"{rmse:.4f}" in r.output  # the printed RMSE is the file's
    assert "20 largest" in " ".join(r.output.split())  # the title may wrap
    assert not _wide_lines(r.output)
    # The printed rows are numbered as the file's index column (0-based data rows), so the
    # largest residual appears under the same number in both.
    worst = max(rows, key=lambda row: abs(float(row["residual_mm"])))
    printed = {
        line.split("│")[1].strip(): line for line in r.output.splitlines() if line.count("│") >= 6
    }
    assert worst["index"] in printed, r.output
    assert f"{float(worst['residual_mm']):+.4f}" in printed[worst["index"]]
    r = _run("verify", str(result), str(data), "--max-rmse-mm", "0.001")
    assert r.exit_code == 1
    r = _run("verify", str(result), str(data), "--refit-anchor")
    assert r.exit_code == 0 and "anchor refit" in r.output


def test_verify_errors_name_the_file(
    cell_and_result: tuple[TrueCell, Path, Path], tmp_path: Path
) -> None:
    _, result, _ = cell_and_result
    bad = tmp_path / "short.csv"
    bad.write_text("q1,q2,q3,q4,q5,q6,L\n1,2,3\n", encoding="utf-8")
    r = _run("verify", str(result), str(bad))
    assert r.exit_code == 2 and "short.csv" in r.output
    r = _run("verify", str(tmp_path / "missing.json"), str(bad))
    assert r.exit_code == 2 and "missing.json" in r.output


def test_tables_fit_80_columns(cell_and_result: tuple[TrueCell, Path, Path]) -> None:
    from calib.compensate import JointTargets, compensate
    from calib.export import model_from_result
    from calib.verify import verify
    from daemon.cli.apply import compensation_summary, verify_tables
    from daemon.datafiles import read_samples

    cell, result_path, data = cell_and_result
    result = json.loads(result_path.read_text())
    nominal = builtin_model("hsr-jr680")
    q = random_poses_deg(cell, 5, np.random.default_rng(1))
    q[0, 4] = 0.0  # a wrist singularity gets flags: the flagged-rows table is printed too
    out = compensate(nominal, model_from_result(result, nominal), JointTargets(q))
    con = Console(width=80, record=True)
    compensation_summary(out, con)
    verify_tables(verify(result, read_samples(data)), con)
    text = con.export_text()
    assert "Compensation (joint targets" in text and "Per-pose residuals" in text
    assert "max residual [mm]" in text and "RMSE [mm]" in text  # units survive the markup
    assert not _wide_lines(text)
