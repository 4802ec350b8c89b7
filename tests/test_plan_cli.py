"""``cablecal plan``: the plan file, its poses, the 80-column summary and named errors."""

from __future__ import annotations

import csv
import dataclasses
import json
import re
from pathlib import Path

import numpy as np
import pytest
from rich.console import Console
from typer.testing import CliRunner

from calib.dataset import make_samples, samples_to_csv
from calib.models import builtin_model
from calib.planning import CSV_COLUMNS, PlanOptions
from calib.planning.candidates import flange_and_tool_mm
from calib.synthetic import make_true_cell, noisy_lengths, random_poses_deg
from daemon.cli import app
from daemon.cli.plan import option_error, summary_renderables

MODEL = builtin_model("hsr-jr680")
ANCHOR = "1430,330,230"
FAST = ["--n", "12", "--candidates", "300", "--seed", "1"]


def _run(args: list[str], columns: int = 80) -> tuple[int, str]:
    res = CliRunner().invoke(app, ["plan", *args], env={"COLUMNS": str(columns)})
    return res.exit_code, res.output


def _read(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as f:
        return list(csv.DictReader(f))


def test_plan_file_poses_and_80_column_summary(tmp_path: Path) -> None:
    out, js = tmp_path / "plan.csv", tmp_path / "plan.json"
    args = ["--anchor-mm", ANCHOR, *FAST, "--min-z-mm", "100", "--extension-mm", "200,1800"]
    code, text = _run([*args, "--out", str(out), "--json", str(js)])
    assert code == 0, text
    rows = _read(out)
    assert list(rows[0]) == list(CSV_COLUMNS) and len(rows) == 12
    q = np.array([[float(r[f"q{j}"]) for j in range(1, 7)] for r in rows])
    limits = np.asarray(MODEL.joint_limits_deg)
    assert np.all((q >= limits[:, 0]) & (q <= limits[:, 1]))
    flange, tool = flange_and_tool_mm(MODEL, q)
    ext = np.linalg.norm(tool - [1430, 330, 230], axis=1)
    # Within the stroke shrunk by the anchor uncertainty (30 mm), above the floor.
    assert np.all((ext >= 230 - 1e-6) & (ext <= 1770 + 1e-6)), ext
    assert np.allclose(ext, [float(r["extension_mm"]) for r in rows], atol=0.06)
    assert np.all(flange[:, 2] >= 100) and np.all(tool[:, 2] >= 100)
    lines = text.splitlines()
    assert max(len(line) for line in lines) <= 80
    # The tables are not squeezed: each figure row is whole on one line, plan beside random.
    summary = json.loads(js.read_text())
    tcp = summary["tcp_sigma_mm"]
    assert any(
        f"{tcp['plan']['rms']:.4f}" in ln and f"{tcp['random']['rms']:.4f}" in ln for ln in lines
    )
    assert tcp["plan"]["rms"] < tcp["random"]["rms"]
    assert any("campaign (moves + dwell)" in ln for ln in lines)
    # Every base parameter's σ is printed.
    for p in summary["parameters"]:
        assert re.search(rf"\b{re.escape(p['name'])}\b", text), p["name"]


def test_several_anchors_and_start_data(tmp_path: Path) -> None:
    out = tmp_path / "two.csv"
    code, text = _run(
        [
            "--anchor-mm",
            ANCHOR,
            "--anchor-mm=-300,1300,300",
            "--anchor-id",
            "A",
            "--anchor-id",
            "B",
            *FAST,
            "--out",
            str(out),
        ]
    )
    assert code == 0, text
    assert "Several anchors against one" in text and "gain over" in text
    assert max(len(line) for line in text.splitlines()) <= 80
    assert {r["anchor"] for r in _read(out)} <= {"A", "B"}
    # Start data without --anchor-mm: the start's anchor (multilaterated) and its id.
    cell = make_true_cell(MODEL, anchors_mm=np.array([[1430.0, 330.0, 230.0]]))
    rng = np.random.default_rng(0)
    q0 = random_poses_deg(cell, 30, rng)
    start = tmp_path / "start.csv"
    start.write_text(samples_to_csv(make_samples(q0, noisy_lengths(cell, q0, rng))))
    code, text = _run([*FAST, "--start", str(start), "--out", str(out)])
    assert code == 0, text
    assert "cond., start data" in text and "note: 30 start samples" in text
    assert {r["anchor"] for r in _read(out)} == {"A"}
    assert abs(float(_read(out)[0]["anchor_x_mm"]) - 1430.0) < 20.0


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--anchor-mm", "1430,330"], "--anchor-mm: expected X,Y,Z in mm"),
        (["--anchor-mm", "1,2,x"], "--anchor-mm: expected X,Y,Z in mm"),
        ([], "--anchor-mm: required"),
        (["--anchor-mm", ANCHOR, "--extension-mm", "500"], "--extension-mm: expected MIN,MAX"),
        (["--anchor-mm", ANCHOR, "--extension-mm", "900,100"], "--extension-mm: need 0 <="),
        (["--anchor-mm", ANCHOR, "--n", "0"], "--n: must be at least 1"),
        (["--anchor-mm", ANCHOR, "--n", "50", "--candidates", "20"], "--candidates: 20 is fewer"),
        (["--anchor-mm", ANCHOR, "--joint-speed-deg-s", "1,2"], "--joint-speed-deg-s: expected"),
        (["--anchor-mm", ANCHOR, "--dwell-s", "-1"], "--dwell-s: must be >= 0"),
        (["--anchor-mm", "9000,0,0"], "--anchor-mm: anchor 1 at"),
        (["--anchor-mm", ANCHOR, "--anchor-id", "A", "--anchor-id", "B"], "--anchor-id: 2 ids"),
        (["--anchor-mm", ANCHOR, "--robot", "nope"], "--robot"),
        (["--anchor-mm", ANCHOR, "--start", "/nonexistent.csv"], "--start /nonexistent.csv"),
    ],
)
def test_bad_input_names_the_option(tmp_path: Path, args: list[str], message: str) -> None:
    out = tmp_path / "p.csv"
    code, text = _run(
        [*args, "--candidates", "200", "--out", str(out)]
        if "--candidates" not in args
        else [*args, "--out", str(out)]
    )
    assert code == 2, text
    assert message in " ".join(text.split()), text
    assert not out.exists()


def test_option_error_maps_engine_names() -> None:
    assert option_error("min_z_mm: fewer than 500") == "--min-z-mm: fewer than 500"
    assert option_error("anchor_ids: 1 ids for 2 anchors") == "--anchor-id: 1 ids for 2 anchors"
    assert option_error("something else entirely") == "something else entirely"


def test_help_states_the_engine_defaults() -> None:
    _, text = _run(["--help"], columns=200)
    flat = " ".join(text.split())
    d = PlanOptions()
    for value in (d.n, d.candidates, d.seed, d.noise_mm, d.anchor_uncertainty_mm):
        assert f"({value:g})" in flat, value
    assert f"({d.dwell_s:g})" in flat
    lo, hi = d.extension_mm
    assert f"({lo:g},{hi:g})" in flat
    assert "(" + ",".join(f"{v:g}" for v in d.joint_speed_deg_s) + ")" in flat
    assert {f.name for f in dataclasses.fields(d)} >= {"n", "min_z_mm", "dwell_s"}


def test_summary_renders_at_80_columns_without_wrapping() -> None:
    data = {
        "n_poses": 40,
        "anchors": {"A": [1430.0, 330.0, 230.0], "B": [-300.0, 1300.0, 300.0]},
        "poses_per_anchor": {"A": 22, "B": 18},
        "noise_mm": 0.05,
        "condition_number": 123.4,
        "condition_number_start": 1.58e6,
        "n_candidates": 20000,
        "exchanges": 200,
        "elapsed_s": 12.3,
        "parameters": [
            {"name": f"theta{j}@B", "sigma": 12345.6789, "unit": "deg"} for j in range(31)
        ],
        "tcp_sigma_mm": {
            "plan": {"rms": 0.0612, "max": 0.1},
            "random": {"rms": 1.2e5, "max": 3.4e6},
        },
        "travel_s": 600.0,
        "campaign_s": 900.0,
        "anchor_gain": {
            "single_anchor": {
                "A": {"kinematic_log_det": 3.2, "tcp_sigma_mm": {"rms": 0.07, "max": 0.1}}
            },
            "all_anchors": {"kinematic_log_det": 3.4, "tcp_sigma_mm": {"rms": 0.06, "max": 0.1}},
            "best_single_anchor": "A",
            "d_efficiency_gain": 1.22,
            "tcp_rms_ratio": 1.17,
            "plan_uses": "all",
        },
        "notes": [],
    }
    console = Console(width=80, record=True, file=open("/dev/null", "w"))  # noqa: SIM115
    for item in summary_renderables(data, has_start=True):
        console.print(item)
    lines = console.export_text().splitlines()
    assert max(len(line) for line in lines) <= 80
    assert any("theta0@B" in ln and "1.23e+04 deg" in ln and "theta1@B" in ln for ln in lines)
    assert any("1.58e+06" in ln for ln in lines)


def test_start_data_give_the_zero_offset_and_every_reading_stays_in_range(
    tmp_path: Path,
) -> None:
    """Issue 27 item 2: the start samples' zero offset (-300 mm: a cable shorter than 300 mm
    reads below 0) keeps every planned pose's predicted reading inside the indicator's range."""
    cell = make_true_cell(
        MODEL, anchors_mm=np.array([[1400.0, 300.0, 200.0]]), offsets_mm=np.array([-300.0])
    )
    rng = np.random.default_rng(3)
    q = random_poses_deg(cell, 30, rng)
    start = tmp_path / "start.csv"
    start.write_text(samples_to_csv(make_samples(q, noisy_lengths(cell, q, rng, noise_mm=0.02))))
    out, js = tmp_path / "plan.csv", tmp_path / "plan.json"
    code, text = _run(
        [
            "--n",
            "24",
            "--candidates",
            "1500",
            "--seed",
            "5",
            "--start",
            str(start),
            "--out",
            str(out),
            "--json",
            str(js),
        ]
    )
    assert code == 0, text
    reading = json.loads(js.read_text())["reading_mm"]
    assert reading["offsets_mm"]["A"] == pytest.approx(-300.0, abs=5.0)
    lo, hi = reading["window_mm"]
    assert lo <= reading["min"] and reading["max"] <= hi
    assert all(float(r["extension_mm"]) - 300.0 >= lo - 5.0 for r in _read(out))
