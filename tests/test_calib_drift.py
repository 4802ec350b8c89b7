"""The drift and steps of the measurement over a campaign (calib.drift), against known truth
on seeded synthetic ABB IRB 120 campaigns (bench.drift_bench), and "none" on clean data."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parent.parent
if str(REPO) not in sys.path:  # bench/ is a top-level package of the repo, not installed
    sys.path.insert(0, str(REPO))

from bench.drift_bench import campaign, tcp_error_mm  # noqa: E402
from calib.dataset import make_samples, parse_samples_csv, samples_to_csv  # noqa: E402
from calib.identify import IdentifyOptions, identify  # noqa: E402
from calib.identify.result_json import drift_summary as summary  # noqa: E402
from calib.models import builtin_model  # noqa: E402
from calib.options import OptionError, options_from_mapping  # noqa: E402
from calib.result import CalibrationResult  # noqa: E402
from calib.synthetic import make_true_cell, noisy_lengths, random_poses_deg  # noqa: E402

N = 300


def _run(case: str, drift: str = "auto", seed: int = 1) -> tuple[float, dict]:  # type: ignore[type-arg]
    cell, samples = campaign(case, N, seed)
    js = identify(cell.model, samples, IdentifyOptions(drift=drift, seed=seed)).to_json()  # type: ignore[arg-type]
    return tcp_error_mm(cell, CalibrationResult.from_json(js)), js


def test_truth_bump_and_rate_within_1_2x_of_clean_and_clean_unchanged() -> None:
    clean_none, _ = _run("clean", "none")
    clean_auto, js = _run("clean")
    assert js["drift"]["model"] == "none"
    assert clean_auto <= 1.02 * clean_none
    for case in ("bump", "rate"):
        tcp, js = _run(case)
        assert tcp <= 1.2 * clean_auto, (case, tcp, clean_auto)
        assert js["drift"]["model"] != "none"
        # without the drift model the same campaign is far off (the test can fail)
        assert _run(case, "none")[0] > 3 * clean_auto


def test_steps_found_at_the_right_row_with_the_right_size_and_kind() -> None:
    _, js = _run("bump")
    (step,) = js["drift"]["steps"]
    assert step["kind"] == "sensor_moved"
    assert abs(step["row"] - N // 2) <= 3
    assert step["size_mm"] == pytest.approx(4.0, abs=0.2)
    assert step["p0_shift_mm"][0] == pytest.approx(4.0, abs=0.2)
    _, js = _run("rezero")
    (step,) = js["drift"]["steps"]
    assert step["kind"] == "rezero"
    assert abs(step["row"] - int(0.6 * N)) <= 3
    assert step["offset_mm"] == pytest.approx(5.0, abs=0.05)
    assert "indicator re-zeroed at row" in summary(js["drift"])


def test_drift_rate_recovered_in_mm_per_h_from_the_t_s_column() -> None:
    cell, samples = campaign("rate", N, 1)
    assert samples.t_s is not None
    back = parse_samples_csv(samples_to_csv(samples))  # the t_s column round-trips
    assert back.t_s is not None and np.allclose(back.t_s, samples.t_s, atol=1e-3)
    js = identify(cell.model, back, IdentifyOptions(drift="smooth")).to_json()
    sm = js["drift"]["smooth"]
    assert js["drift"]["time_unit"] == "s"
    assert sm["mean_rate_mm_per_h"] == pytest.approx(2.0, rel=0.05)


def test_auto_answers_none_on_clean_emulated_cells_and_the_bundled_hsr_data() -> None:
    cell = make_true_cell(builtin_model("hsr-jr680"))
    for seed in (3, 4, 5):
        rng = np.random.default_rng(seed)
        q = random_poses_deg(cell, 120, rng)
        s = make_samples(q, noisy_lengths(cell, q, rng, noise_mm=0.02))
        res = identify(cell.model, s, IdentifyOptions(seed=seed))
        assert res.drift is not None and res.drift["model"] == "none", res.drift
    data = REPO / "calib" / "data" / "hsr-robotcali.csv"
    hsr = parse_samples_csv(data.read_text())
    res = identify(builtin_model("hsr-jr680"), hsr)
    assert res.drift is not None and res.drift["model"] == "none", res.drift


def test_drift_option_is_validated_by_name() -> None:
    assert options_from_mapping({"drift": "steps"}).drift == "steps"
    with pytest.raises(OptionError, match="drift"):
        options_from_mapping({"drift": "sometimes"})


def test_cli_summary_names_the_step_at_80_columns(tmp_path: Path) -> None:
    """``cablecal identify`` says what moved, where and by how much, in a 80-column terminal;
    ``--drift none`` leaves it out and the fit is far worse."""
    import json
    import os
    import subprocess

    _, samples = campaign("bump", N, 1)
    data = tmp_path / "bump.csv"
    data.write_text(samples_to_csv(samples))
    base = [
        sys.executable,
        "-m",
        "daemon.cli",
        "identify",
        str(data),
        "--robot",
        str(REPO / "examples" / "abb-irb120.toml"),
    ]
    env = {**os.environ, "COLUMNS": "80", "NO_COLOR": "1"}
    proc = subprocess.run(
        [*base, "--out", str(tmp_path / "r.json")],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    )
    flat = " ".join((proc.stdout + proc.stderr).split())
    assert "drift auto: sensor moved at row 15" in flat, flat
    assert max(len(line) for line in proc.stdout.splitlines()) <= 80
    assert json.loads((tmp_path / "r.json").read_text())["drift"]["model"] == "steps"
    off = subprocess.run(
        [*base, "--drift", "none"],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert "sensor moved" not in off.stdout


def test_the_summary_never_says_held_still_while_samples_sit_millimetres_off() -> None:
    """Issue 27 item 1: five samples after a 3 mm move left in the old anchor session (the
    watch split late) were set aside as outliers, and the summary said "held still"."""
    from calib.dataset import SampleSet
    from simulator.cell import EmulatedCell
    from simulator.config import SimConfig

    cell = EmulatedCell(SimConfig(seed=4, robot={"n_poses": 42}))
    q = np.vstack([cell.poses_deg[:42]] * 2)  # the same program run twice
    lengths = cell.truth.lengths_mm(q)
    cell.move_anchor([3.0, 0.0, 0.0])
    lengths[65:] = cell.truth.lengths_mm(q[65:])
    lengths = np.round((lengths + np.random.default_rng(1).normal(0, 0.02, 84)) / 0.01) * 0.01

    def drift_block(split: int) -> dict:  # type: ignore[type-arg]
        anchors = tuple("A" if i < split else "A2" for i in range(84))
        samples = SampleSet(
            joints_deg=q, length_mm=lengths, anchor=anchors, group=None, line=np.arange(2, 86)
        )
        block: dict = identify(cell.truth.model, samples).to_json()["drift"]  # type: ignore[type-arg]
        return block

    late = drift_block(70)  # rows 65..69 were taken after the move
    aside = sorted({*late["rows_left_out_of_the_choice"], *late["rows_flagged"]})
    assert aside and set(aside) <= set(range(65, 70)), aside
    assert "held still" not in late["summary"]
    assert f"{len(aside)} sample(s) left out as outliers (rows {aside[0]}," in late["summary"]
    right = drift_block(65)
    assert right["rows_flagged"] == [] and right["rows_left_out_of_the_choice"] == []
    assert right["summary"] == "drift auto: none found (the measurement held still)"
