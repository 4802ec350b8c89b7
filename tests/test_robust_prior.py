"""Issue 10, goals 2–5: robust by default, the prior's weight, exit codes, the advice."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from calib import robust
from calib.cable import N_DH, N_KIN, predict_lengths
from calib.dataset import make_samples, samples_to_csv
from calib.identify import IdentifyOptions, identify
from calib.kinematics import N_JOINTS, forward_position
from calib.models import builtin_model
from calib.robust import auto_threshold
from calib.synthetic import TrueCell, make_true_cell, noisy_lengths, random_poses_deg
from calib.tcp import aligned_position_error_mm, workspace_sample_deg
from daemon.cli import app

MODEL = builtin_model("hsr-jr680")
SEEDS = range(5)
N_TRAIN, N_TEST = 100, 200


def _tool_positions_mm(theta: np.ndarray, q_deg: np.ndarray) -> np.ndarray:
    """Hook points (m, 3) [mm] of the model ``theta`` at poses (m, 6) [deg]."""
    dh = MODEL.dh_internal() + theta[:N_DH].reshape(N_JOINTS, 4)
    return forward_position(
        dh, np.deg2rad(q_deg), MODEL.tool_mm + theta[N_DH:N_KIN], MODEL.convention
    )


def _errors(cell: TrueCell, theta: np.ndarray, q_test: np.ndarray) -> tuple[float, float]:
    """RMS length error against the true lengths at the test poses, and RMS aligned TCP
    position error over a workspace sample [mm]."""
    pred = predict_lengths(MODEL, theta, np.deg2rad(q_test), np.zeros(len(q_test), int))
    length = float(np.sqrt(np.mean((pred - cell.lengths_mm(q_test)) ** 2)))
    qw = workspace_sample_deg(MODEL, 300, seed=1)
    tcp = aligned_position_error_mm(_tool_positions_mm(theta, qw), cell.tool_positions_mm(qw))
    return length, float(np.sqrt(np.mean(tcp**2)))


@pytest.fixture(scope="module")
def robust_runs() -> dict[str, np.ndarray]:
    """Per seed: (length, tcp) errors of the plain fit on clean data, the default (auto) on
    clean data and on 5 % gross outliers (5–20 mm), and whether auto flagged exactly them."""
    cell = make_true_cell(MODEL)
    train, test = np.arange(N_TRAIN), np.arange(N_TRAIN, N_TRAIN + N_TEST)
    out: dict[str, list[tuple[float, float]]] = {"plain": [], "auto_clean": [], "auto_out": []}
    exact: list[bool] = []
    for seed in SEEDS:
        rng = np.random.default_rng(100 + seed)
        q = random_poses_deg(cell, N_TRAIN + N_TEST, rng)
        noisy = noisy_lengths(cell, q, rng, noise_mm=0.05)
        bad = rng.choice(train, 5, replace=False)
        corrupted = noisy.copy()
        corrupted[bad] += rng.choice([-1, 1], 5) * rng.uniform(5, 20, 5)
        plain = identify(
            MODEL,
            make_samples(q, noisy),
            IdentifyOptions(robust="none"),
            train_rows=train,
            test_rows=test,
        )
        auto = identify(
            MODEL, make_samples(q, noisy), IdentifyOptions(), train_rows=train, test_rows=test
        )
        dirty = identify(
            MODEL, make_samples(q, corrupted), IdentifyOptions(), train_rows=train, test_rows=test
        )
        assert auto.flagged_rows == []
        np.testing.assert_array_equal(auto.theta, plain.theta)  # the plain fit itself
        exact.append(sorted(dirty.flagged_rows) == sorted(bad.tolist()))
        out["plain"].append(_errors(cell, plain.theta, q[test]))
        out["auto_clean"].append(_errors(cell, auto.theta, q[test]))
        out["auto_out"].append(_errors(cell, dirty.theta, q[test]))
    arrays = {k: np.array(v) for k, v in out.items()}
    arrays["exact"] = np.array(exact)
    return arrays


def test_auto_is_the_default_and_gives_the_plain_fit_on_clean_data(robust_runs) -> None:
    assert IdentifyOptions().robust == "auto"
    ratio = robust_runs["auto_clean"].mean(axis=0) / robust_runs["plain"].mean(axis=0)
    assert np.all(ratio <= 1.01), ratio


def test_auto_with_gross_outliers_stays_within_1_1x_of_clean_in_length_and_tcp(
    robust_runs,
) -> None:
    ratio = robust_runs["auto_out"].mean(axis=0) / robust_runs["plain"].mean(axis=0)
    assert ratio[0] <= 1.1, f"length ratio {ratio[0]:.3f}"
    assert ratio[1] <= 1.1, f"aligned TCP ratio {ratio[1]:.3f}"
    assert robust_runs["exact"].all()  # the outliers, and nothing else, are flagged


def test_auto_threshold_grows_with_n_and_respects_flag_threshold() -> None:
    assert 3.8 < auto_threshold(100, 3.5) < 4.0
    assert auto_threshold(2000, 3.5) > auto_threshold(100, 3.5)
    assert auto_threshold(10, 6.0) == 6.0


# ---------------------------------------------------------------- the prior's weight


def _spread_case(n: int, noise_mm: float, seed: int = 3) -> tuple[np.ndarray, np.ndarray]:
    cell = make_true_cell(MODEL)
    rng = np.random.default_rng(seed)
    q = random_poses_deg(cell, n, rng)
    return q, noisy_lengths(cell, q, rng, noise_mm=noise_mm)


@pytest.mark.parametrize("noise_mm", [0.05, 0.5])
def test_estimated_noise_tracks_the_data_as_n_grows(noise_mm: float) -> None:
    """The prior weighs as the data's own noise at any n; a fixed 0.1 mm does not."""
    for n in (60, 400):
        q, lengths = _spread_case(n, noise_mm)
        opts = IdentifyOptions(method="lm", test_fraction=0.0, prior=True)
        block = identify(MODEL, make_samples(q, lengths), opts).to_json()["prior"]
        assert block["weight"] == "estimated" and block["applied"]
        assert 0.7 * noise_mm < block["noise_mm"] < 1.3 * noise_mm, (n, block)
        fixed = identify(
            MODEL,
            make_samples(q, lengths),
            IdentifyOptions(method="lm", test_fraction=0.0, prior=True, prior_weight="fixed"),
        ).to_json()["prior"]
        assert fixed["noise_mm"] == 0.1


def test_cv_reports_its_scores_and_uses_the_best_scale() -> None:
    q, lengths = _spread_case(120, 0.05)
    opts = IdentifyOptions(method="lm", test_fraction=0.0, prior=True, prior_weight="cv")
    block = identify(MODEL, make_samples(q, lengths), opts).to_json()["prior"]
    scores = block["cv_rmse_mm"]
    assert set(scores) == {"0.25", "1.0", "4.0", "16.0", "inf"}
    best = min(scores, key=scores.get)
    assert block["cv_scale"] == (None if best == "inf" else float(best))
    if best != "inf":
        assert block["dh_mm"] == pytest.approx(2.0 * float(best))


# ---------------------------------------------------------------- exit codes and advice


def _csv(tmp_path: Path, name: str, q: np.ndarray, lengths: np.ndarray) -> Path:
    path = tmp_path / name
    path.write_text(samples_to_csv(make_samples(q, lengths)))
    return path


@pytest.fixture(scope="module")
def cases(tmp_path_factory) -> dict[str, Path]:
    """good: well spread; local: a few degrees (by maximum likelihood, --no-prior, LM does not
    converge; the default MAP fit does);
    long_tool: a 600 mm hook point (converges, implausible: tool beyond 500 mm)."""
    tmp = tmp_path_factory.mktemp("exit")
    cell = make_true_cell(MODEL)
    rng = np.random.default_rng(0)
    q = random_poses_deg(cell, 60, rng)
    centre = random_poses_deg(cell, 1, rng)[0]
    q_local = random_poses_deg(cell, 60, rng, spread_deg=2.0, centre_deg=centre)
    long_tool = make_true_cell(MODEL, tool_error_mm=np.array([0.0, 0.0, 600.0]))
    q_long = random_poses_deg(long_tool, 60, rng)
    bad = tmp / "bad.csv"
    bad.write_text("q1,q2,q3,q4,q5,q6,L\n0,0,0,0,0,0,nan\n")
    return {
        "good": _csv(tmp, "good.csv", q, noisy_lengths(cell, q, rng)),
        "local": _csv(tmp, "local.csv", q_local, noisy_lengths(cell, q_local, rng)),
        "long_tool": _csv(tmp, "long.csv", q_long, noisy_lengths(long_tool, q_long, rng)),
        "bad": bad,
    }


def _identify(path: Path, *extra: str) -> tuple[int, str, dict]:
    out = path.with_suffix(".json")
    out.unlink(missing_ok=True)
    args = ["identify", str(path), "--method", "lm", "--test-fraction", "0", "--out", str(out)]
    res = CliRunner().invoke(app, [*args, *extra], env={"COLUMNS": "200"})
    data = json.loads(out.read_text()) if out.exists() else {}
    return res.exit_code, res.output, data


def test_exit_codes(cases: dict[str, Path]) -> None:
    code, _, data = _identify(cases["good"], "--strict")
    assert code == 0 and data["success"] and data["plausibility"]["plausible"]
    code, output, data = _identify(cases["local"], "--no-prior")
    assert code == 1 and not data["success"]  # written, and the exit says not converged
    assert "not converged" in output
    code, output, data = _identify(cases["local"])  # the default MAP fit is well posed
    assert code == 0 and data["success"] and data["plausibility"]["plausible"]
    code, _, data = _identify(cases["bad"])
    assert code == 2 and data == {}
    code, _, data = _identify(cases["long_tool"])
    assert code == 0 and data["success"] and not data["plausibility"]["plausible"]
    code, output, data = _identify(cases["long_tool"], "--strict")
    assert code == 3 and data["plausibility"]["outside_bounds"] == ["tool_z"]
    assert "implausible" in output


def test_help_documents_the_exit_codes() -> None:
    res = CliRunner().invoke(app, ["identify", "--help"], env={"COLUMNS": "200"})
    assert res.exit_code == 0
    for text in ("--strict", "Exit codes", "not converge", "bad input", "implausible"):
        assert text in res.output, text


def _advice(data: dict) -> str:
    notes = [n for n in data["notes"] if "implausible" in n]
    assert len(notes) == 1, data["notes"]
    return notes[0]


def test_advice_names_parameters_and_is_never_circular(cases: dict[str, Path]) -> None:
    _, _, off = _identify(cases["local"], "--no-prior")
    text = _advice(off)
    assert "cablecal plan --start" in text
    named = [n for n in off["correlation"]["names"] if f"{n} ±" in text]
    assert len(named) >= 3, text  # the least constrained solved parameters, by name
    assert "--prior" in text  # off: may be suggested
    _, _, on = _identify(cases["local"])  # the prior is on by default
    assert on["plausibility"]["plausible"]  # here the prior is enough: no advice at all
    _, _, on = _identify(cases["long_tool"])  # a 600 mm tool: no prior holds it
    text = _advice(on)
    assert on["prior"]["used"] and "cablecal plan --start" in text
    assert "--prior" not in text  # on already: never advised
    assert "weakest direction" in text


def test_median_agrees_with_numpy_without_loading_numpy_ma() -> None:
    """calib.robust.median is np.median (odd, even, NaN, empty, 2-D) and, unlike it, never
    imports numpy.ma (a cost of every identify's first call)."""
    rng = np.random.default_rng(3)
    for n in (1, 2, 3, 10, 11, 257):
        x = rng.normal(size=n)
        assert robust.median(x) == float(np.median(x))
    x2 = rng.normal(size=(4, 5))
    assert robust.median(x2) == float(np.median(x2))
    assert np.isnan(robust.median(np.array([1.0, np.nan, 2.0])))
    assert np.isnan(robust.median(np.zeros(0)))
    code = (
        "import sys, numpy as np; from calib.robust import median; "
        "median(np.arange(5.0)); print('numpy.ma' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
