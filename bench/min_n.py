"""Identification near the minimum sample count on clean and contaminated virtual cells.

Issue 22: at the minimum count (31 rows: 25 training, 6 test, for about 24 solved
parameters) the noise estimate collapsed and ``robust auto`` flagged good samples. This
measures, for each row count, over :data:`N_CELLS` seeded VIRTUAL cells (:func:`virtual_cell`:
random DH, tool and anchor errors; random poses; Gaussian noise of :data:`NOISE_MM`; lengths
rounded to the indicator's :data:`STEP_MM` as the real indicator reports them; no outliers),
identify with its default options and the random 80/20 split:

- how many cells had any sample flagged, and how many samples in all (every one is a good
  sample: the cells are clean);
- the median over cells of the noise the prior was weighed with (``prior.noise_mm``), and of
  its ratio to the truth, the ratio's quartiles, and the chance that the median of 8 cells
  (the outside check ``calib-min-n``) falls outside 0.8–1.25 × the truth (issue 27);
- the same at 31 and 45 rows on the EMULATED cells (:func:`emulated_case`).

Unless ``--no-outliers``, it also measures 5 % gross outliers (5–20 mm) in the training rows
at 45, 60 and 100 rows (:data:`OUTLIER_CELLS` cells): the aligned TCP error of the default
fit against the plain fit on the clean lengths (the test of ``tests/test_min_n.py``).

Writes ``bench/min_n.json`` and ``bench/min_n.md`` (``--label`` names the column set, so a
run before and after a change can be kept side by side: the table keeps every label's rows).
Run ``python -m bench.min_n`` (through ``make bench``).
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from calib.cable import N_DH, N_KIN
from calib.dataset import make_samples
from calib.default_robot import DEFAULT_ROBOT_MODEL
from calib.identify import IdentifyOptions, identify
from calib.identify.result_json import IdentifyResult
from calib.kinematics import N_JOINTS, FloatArray, forward_position
from calib.models import RobotModel, builtin_model
from calib.result import CalibrationResult
from calib.synthetic import TrueCell, make_true_cell, noisy_lengths, random_poses_deg
from calib.tcp import aligned_position_error_mm, workspace_sample_deg

OUT = Path(__file__).parent
MODEL = builtin_model(DEFAULT_ROBOT_MODEL)
#: Cells (pose sets) per row count of the clean tables: at the minimum count one cell's
#: noise estimate spreads widely (its quartiles are in the table), so a median over a few
#: cells measures the draw more than the estimator.
N_CELLS = 96
#: Cells per row count of the outlier comparison (two fits each, at up to 100 rows).
OUTLIER_CELLS = 24
#: The outside check's sample: the median of this many cells must lie in NOISE_BAND × truth.
CHECK_CELLS = 8
NOISE_BAND = (0.8, 1.25)
#: Row counts of the EMULATED cells' table (the simulator's cells, as the outside check).
EMULATED_ROWS = (31, 45)
#: The cells' length noise, 1σ [mm] (the emulated cell's default).
NOISE_MM = 0.02
#: The indicator's display step [mm] (two decimals, the emulated cell's default).
STEP_MM = 0.01
#: Row counts measured: the minimum for one anchor, the issue's 45 and the paper's 100.
ROWS = (31, 45, 100)
#: Row counts and share of the outlier comparison (45: two outliers that can mask each other).
OUTLIER_ROWS = (45, 60, 100)
OUTLIER_FRACTION = 0.05


@dataclass(frozen=True)
class Case:
    """One virtual cell's samples: the truth, poses (n, 6) [deg], clean-noise lengths (n,)
    [mm] (rounded to the step) and, with outliers, the corrupted lengths and their rows."""

    cell: TrueCell
    q_deg: FloatArray
    length_mm: FloatArray
    corrupted_mm: FloatArray
    bad_rows: np.ndarray
    train_rows: np.ndarray
    test_rows: np.ndarray


def virtual_cell(seed: int, model: RobotModel = MODEL) -> TrueCell:
    """A seeded VIRTUAL cell: DH errors of about the size of the paper's Table XII (1σ 1 mm,
    0.05°), a tool error of 1σ 1 mm and an anchor within ±150 mm of the emulated cell's."""
    rng = np.random.default_rng([22, seed])
    sd = np.array([0.05, 1.0, 1.0, 0.05])
    errors = rng.normal(0.0, 1.0, (N_JOINTS, 4)) * sd
    anchor = np.array([1400.0, 300.0, 200.0]) + rng.uniform(-150.0, 150.0, 3)
    return make_true_cell(
        model,
        dh_errors_deg_mm=errors,
        tool_error_mm=rng.normal(0, 1.0, 3),
        anchors_mm=anchor[None, :],
    )


def case(seed: int, n_rows: int, outlier_fraction: float = 0.0) -> Case:
    """``n_rows`` samples of virtual cell ``seed``, the random 80/20 split identify's default
    draws (seed 0), and with ``outlier_fraction`` > 0 that share of the training rows pushed
    by 5–20 mm either way."""
    from calib.split import split_rows

    cell = virtual_cell(seed)
    rng = np.random.default_rng([22, seed, n_rows])
    q = random_poses_deg(cell, n_rows, rng)
    lengths = np.round(noisy_lengths(cell, q, rng, noise_mm=NOISE_MM) / STEP_MM) * STEP_MM
    samples = make_samples(q, lengths)
    train, test = split_rows(samples, 0.2, 0, "random", 10)
    n_bad = round(outlier_fraction * train.size)
    bad = rng.choice(train, n_bad, replace=False) if n_bad else np.zeros(0, dtype=int)
    corrupted = lengths.copy()
    corrupted[bad] += np.round(rng.choice([-1, 1], n_bad) * rng.uniform(5, 20, n_bad), 2)
    return Case(cell, q, lengths, corrupted, bad, train, test)


def tcp_error_mm(cell: TrueCell, theta: FloatArray, model: RobotModel = MODEL) -> float:
    """RMS aligned hook-point position error [mm] of ``theta`` over 300 workspace poses."""
    qw = workspace_sample_deg(model, 300, seed=1)
    dh = model.dh_internal() + theta[:N_DH].reshape(N_JOINTS, 4)
    pts = forward_position(dh, np.deg2rad(qw), model.tool_mm + theta[N_DH:N_KIN], model.convention)
    err = aligned_position_error_mm(pts, cell.tool_positions_mm(qw))
    return float(np.sqrt(np.mean(err**2)))


def emulated_case(seed: int, n_rows: int) -> tuple[RobotModel, FloatArray, FloatArray]:
    """The model, ``n_rows`` poses (n, 6) [deg] and clean-noise lengths (n,) [mm] (rounded to
    the step) of EMULATED cell ``seed`` (:class:`simulator.cell.EmulatedCell`: the HSR JR680
    with the paper's Table XII errors, anchor (1400, 300, 200) mm, its seeded pose list)."""
    from simulator.cell import EmulatedCell
    from simulator.config import RobotSection, SimConfig

    cell = EmulatedCell(SimConfig(seed=seed, robot=RobotSection(n_poses=n_rows)))
    q = cell.poses_deg[:n_rows]
    rng = np.random.default_rng([27, seed, n_rows])
    noisy = cell.truth.lengths_mm(q) + rng.normal(0.0, NOISE_MM, n_rows)
    return cell.truth.model, q, np.round(noisy / STEP_MM) * STEP_MM


def _fit_noise_mm(fit: IdentifyResult) -> float:
    """The noise the fit ran with [mm] (``prior.noise_mm`` of its result)."""
    prior = CalibrationResult.from_json(fit.to_json()).prior
    assert prior is not None and prior.noise_mm is not None
    return prior.noise_mm


def clean_row(n_rows: int, cells: int = N_CELLS, emulated: bool = False) -> dict[str, Any]:
    """Flags and noise estimates of the default identify over ``cells`` clean cells (the
    seeded VIRTUAL cells, or with ``emulated`` the EMULATED cells)."""
    flagged, noise, notes = [], [], []
    t0 = time.perf_counter()
    for seed in range(cells):
        if emulated:
            model, q, lengths = emulated_case(seed, n_rows)
            res = identify(model, make_samples(q, lengths), IdentifyOptions())
        else:
            c = case(seed, n_rows)
            res = identify(MODEL, make_samples(c.q_deg, c.length_mm), IdentifyOptions())
        flagged.append(len(res.flagged_rows))
        noise.append(_fit_noise_mm(res))
        notes.append(next((n for n in res.notes if n.startswith("robust")), ""))
    return {
        "rows": n_rows,
        "cells": cells,
        "cells_flagged": int(np.count_nonzero(flagged)),
        "samples_flagged": int(np.sum(flagged)),
        "noise_median_mm": float(np.median(noise)),
        "noise_ratio": float(np.median(noise) / NOISE_MM),
        "noise_ratio_quartiles": [float(v) for v in np.percentile(noise, [25, 75]) / NOISE_MM],
        "noise_mm": noise,
        "robust_notes": notes,
        "time_s": time.perf_counter() - t0,
    }


def outlier_row(n_rows: int, cells: int = OUTLIER_CELLS) -> dict[str, Any]:
    """Aligned TCP error of the default fit on 5 % outliers vs the plain fit on clean data."""
    plain, dirty, exact = [], [], 0
    for seed in range(cells):
        c = case(seed, n_rows, OUTLIER_FRACTION)
        kw = {"train_rows": c.train_rows, "test_rows": c.test_rows}
        ref = identify(
            MODEL, make_samples(c.q_deg, c.length_mm), IdentifyOptions(robust="none"), **kw
        )
        res = identify(MODEL, make_samples(c.q_deg, c.corrupted_mm), IdentifyOptions(), **kw)
        plain.append(tcp_error_mm(c.cell, ref.theta))
        dirty.append(tcp_error_mm(c.cell, res.theta))
        exact += sorted(res.flagged_rows) == sorted(c.bad_rows.tolist())
    return {
        "rows": n_rows,
        "cells": cells,
        "tcp_plain_clean_mm": float(np.mean(plain)),
        "tcp_default_outliers_mm": float(np.mean(dirty)),
        "ratio": float(np.mean(dirty) / np.mean(plain)),
        "cells_exactly_flagged": exact,
    }


def _quartiles(r: dict[str, Any]) -> str:
    q = np.percentile(r["noise_mm"], [25, 75]) / NOISE_MM
    return f"{q[0]:.2f}–{q[1]:.2f}"


def outside_band(noise_mm: list[float], draws: int = 20000) -> float:
    """The chance that the median of :data:`CHECK_CELLS` cells drawn from these (with
    replacement, seeded) lies outside :data:`NOISE_BAND` × the truth."""
    ratio = np.asarray(noise_mm) / NOISE_MM
    picks = np.random.default_rng(27).integers(0, ratio.size, (draws, CHECK_CELLS))
    med = np.median(ratio[picks], axis=1)
    return float(np.mean((med < NOISE_BAND[0]) | (med > NOISE_BAND[1])))


def _outside(r: dict[str, Any]) -> str:
    return f"{outside_band(r['noise_mm']):.2f}" if r["cells"] >= 20 else "–"


def _clean_table(runs: dict[str, Any], key: str) -> list[str]:
    lines = [
        "| run | rows | cells with good samples flagged | samples flagged | noise median [mm] "
        f"| × truth | × truth, 25–75 % | median of {CHECK_CELLS} outside "
        f"{NOISE_BAND[0]}–{NOISE_BAND[1]} |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for label, run in runs.items():
        for r in run.get(key, []):
            lines.append(
                f"| {label} | {r['rows']} | {r['cells_flagged']} of {r['cells']} | "
                f"{r['samples_flagged']} | {r['noise_median_mm']:.4f} | "
                f"{r['noise_ratio']:.2f} | {_quartiles(r)} | {_outside(r)} |"
            )
    return lines


def _markdown(runs: dict[str, Any]) -> str:
    lines = [
        "# Identification near the minimum sample count (issues 22 and 27)",
        "",
        "Seeded VIRTUAL cells per row count (random DH, tool and anchor errors; "
        f"random poses; noise {NOISE_MM} mm, lengths rounded to {STEP_MM} mm; no outliers; "
        f"{N_CELLS} by default, each row says how many), default `identify` (random 80/20 "
        "split). Every flagged sample is a good sample. The noise is the one the prior was "
        "weighed with; × truth is the median over cells, its quartiles show the spread of "
        f"one cell's estimate, and the last column is the chance that {CHECK_CELLS} cells' "
        f"median falls outside {NOISE_BAND[0]}–{NOISE_BAND[1]} × the truth (the outside check "
        "`calib-min-n`; resampled from the row's cells). Generated by `python -m bench.min_n`.",
        "",
        *_clean_table(runs, "clean"),
    ]
    if any(run.get("emulated") for run in runs.values()):
        lines += [
            "",
            "EMULATED cells (`simulator.cell.EmulatedCell`, seeds 0…: the HSR JR680 with the "
            "paper's Table XII errors, anchor (1400, 300, 200) mm, the cell's seeded pose "
            "list), the same noise and step:",
            "",
            *_clean_table(runs, "emulated"),
        ]
    if any(run.get("outliers") for run in runs.values()):
        lines += [
            "",
            f"With {OUTLIER_FRACTION:.0%} gross outliers (5–20 mm) in the training rows: mean "
            "aligned TCP error of the default fit against the plain fit on the clean lengths.",
            "",
            "| run | rows | plain, clean [mm] | default, outliers [mm] | ratio "
            "| cells with exactly "
            "the outliers flagged |",
            "|---|---:|---:|---:|---:|---:|",
        ]
        for label, run in runs.items():
            for r in run.get("outliers", []):
                lines.append(
                    f"| {label} | {r['rows']} | {r['tcp_plain_clean_mm']:.4f} | "
                    f"{r['tcp_default_outliers_mm']:.4f} | {r['ratio']:.3f} | "
                    f"{r['cells_exactly_flagged']} of {r['cells']} |"
                )
    machine = next(iter(runs.values()))["machine"]
    lines += ["", f"Machine: {machine}.", ""]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--label", default="current")
    parser.add_argument("--cells", type=int, default=N_CELLS)
    parser.add_argument("--outlier-cells", type=int, default=OUTLIER_CELLS)
    parser.add_argument("--no-outliers", action="store_true")
    parser.add_argument("--out", type=Path, default=OUT)
    args = parser.parse_args(argv)
    path = args.out / "min_n.json"
    runs: dict[str, Any] = json.loads(path.read_text()) if path.exists() else {}
    run: dict[str, Any] = {
        "machine": f"{platform.machine()}, Python {platform.python_version()}",
        "clean": [clean_row(n, args.cells) for n in ROWS],
        "emulated": [clean_row(n, args.cells, emulated=True) for n in EMULATED_ROWS],
    }
    if not args.no_outliers:
        run["outliers"] = [outlier_row(n, args.outlier_cells) for n in OUTLIER_ROWS]
    runs[args.label] = run
    path.write_text(json.dumps(runs, indent=2) + "\n")
    (args.out / "min_n.md").write_text(_markdown(runs))
    print(_markdown({args.label: run}))
    return runs


if __name__ == "__main__":
    main()
