"""Grouped hold-out RMSE with the MAP prior at the fixed 0.1 mm noise and at the estimated one.

For each grouped split (the same distinct seeds as :mod:`bench.real_data`), three fits on the
training rows with ``--method``: maximum likelihood, MAP with ``noise_mm = 0.1`` (today's
default), and MAP with ``noise_mm`` estimated from the ML residuals
(:func:`calib.prior.estimate_noise_mm`). Reports test RMSE and the largest DH length error.
Writes ``bench/prior_weight.json`` and ``.md``. Run ``python -m bench.prior_weight``.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from bench.real_data import GROUPED_TEST_FRACTION, ROBOT, distinct_grouped_seeds
from calib.identify import IdentifyOptions, identify, split_rows
from calib.prior import estimate_noise_mm
from daemon.datafiles import load_robot, read_samples

OUT = Path(__file__).parent


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--method", default="lm")
    parser.add_argument("--splits", type=int, default=10)
    parser.add_argument("--out", type=Path, default=OUT)
    args = parser.parse_args(argv)
    model, samples = load_robot(ROBOT), read_samples(None)
    base = IdentifyOptions(method=args.method, holdout="grouped",
                           test_fraction=GROUPED_TEST_FRACTION)  # fmt: skip
    rows: list[dict[str, Any]] = []
    for seed in distinct_grouped_seeds(samples, args.splits):
        train, test = split_rows(samples, GROUPED_TEST_FRACTION, seed, "grouped", base.n_groups)
        sigma = estimate_noise_mm(model, samples, replace(base, seed=seed), train)
        variants = {"ml": replace(base, seed=seed),
                    "map, noise 0.1 mm": replace(base, seed=seed, prior=True),
                    "map, noise estimated": replace(base, seed=seed, prior=True,
                                                    noise_mm=sigma)}  # fmt: skip
        for label, opts in variants.items():
            res = identify(model, samples, opts, train_rows=train, test_rows=test)
            dh = res.dh_table_deg_mm(errors_only=True)[:, 1:3]
            rows.append({"seed": seed, "variant": label, "noise_mm": opts.noise_mm,
                         "test_rmse_mm": res.metrics["after"]["test"]["rmse_mm"],
                         "train_rmse_mm": res.metrics["after"]["train"]["rmse_mm"],
                         "max_dh_length_error_mm": float(np.abs(dh).max())})  # fmt: skip
            print(f"seed {seed} {label:22s} noise {opts.noise_mm:.3f} test "
                  f"{rows[-1]['test_rmse_mm']:.3f} mm, max DH "
                  f"{rows[-1]['max_dh_length_error_mm']:.1f} mm", flush=True)  # fmt: skip
    data = {"method": args.method, "runs": rows}
    lines = [f"# MAP prior weight on grouped hold-out ({args.method})", "",
             "| variant | mean noise_mm | mean test RMSE [mm] | worst [mm] | "
             "median max DH length error [mm] |", "|---|---:|---:|---:|---:|"]  # fmt: skip
    for label in dict.fromkeys(r["variant"] for r in rows):
        sel = [r for r in rows if r["variant"] == label]
        scores = [r["test_rmse_mm"] for r in sel]
        lines.append(f"| {label} | {np.mean([r['noise_mm'] for r in sel]):.3f} | "
                     f"{np.mean(scores):.3f} | {np.max(scores):.3f} | "
                     f"{np.median([r['max_dh_length_error_mm'] for r in sel]):.1f} |")  # fmt: skip
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "prior_weight.json").write_text(json.dumps(data, indent=1) + "\n")
    (args.out / "prior_weight.md").write_text("\n".join(lines) + "\n")
    return data


if __name__ == "__main__":
    main()
