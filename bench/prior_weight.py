"""Grouped hold-out RMSE without the prior and with each way of weighing it.

For each grouped split (the same distinct seeds as :mod:`bench.real_data`), fits on the
training rows with ``--method``: maximum likelihood, MAP with ``prior_weight`` ``fixed``
(``noise_mm = 0.1``), ``estimated`` (noise from the ML residuals) and ``cv`` (prior scale by
grouped-fold cross-validation, :mod:`calib.prior`). Reports test RMSE, the noise and scale
used, the largest DH length error and the time. Writes ``bench/prior_weight.json`` and ``.md``.
Run ``python -m bench.prior_weight [--splits N] [--variants ml,fixed,estimated,cv]``.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from bench.real_data import GROUPED_TEST_FRACTION, ROBOT, distinct_grouped_seeds
from calib.identify import IdentifyOptions, identify, split_rows
from calib.result import CalibrationResult
from daemon.datafiles import load_robot, read_samples

OUT = Path(__file__).parent


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--method", default="lm")
    parser.add_argument("--splits", type=int, default=10)
    parser.add_argument("--variants", default="ml,fixed,estimated,cv")
    parser.add_argument("--robust", default="none")
    parser.add_argument("--first", type=int, default=0, help="Skip the first splits")
    parser.add_argument("--out", type=Path, default=OUT)
    args = parser.parse_args(argv)
    model, samples = load_robot(ROBOT), read_samples(None)
    base = IdentifyOptions(
        method=args.method,
        holdout="grouped",
        test_fraction=GROUPED_TEST_FRACTION,
        robust=args.robust,
    )
    rows: list[dict[str, Any]] = []
    for seed in distinct_grouped_seeds(samples, args.splits)[args.first :]:
        train, test = split_rows(samples, GROUPED_TEST_FRACTION, seed, "grouped", base.n_groups)
        variants = {
            "ml": replace(base, seed=seed, prior=False),
            "map, noise 0.1 mm": replace(base, seed=seed, prior=True, prior_weight="fixed"),
            "map, noise estimated": replace(base, seed=seed, prior=True),
            "map, scale by grouped CV": replace(base, seed=seed, prior=True, prior_weight="cv"),
        }
        keys = dict(zip(("ml", "fixed", "estimated", "cv"), variants, strict=True))
        for key in args.variants.split(","):
            label = keys[key]
            t0 = time.perf_counter()
            res = identify(model, samples, variants[label], train_rows=train, test_rows=test)
            dh = res.dh_table_deg_mm(errors_only=True)[:, 1:3]
            loaded = CalibrationResult.from_json(res.to_json())
            pb = loaded.prior.block if loaded.prior else {}
            rows.append(
                {
                    "seed": seed,
                    "variant": label,
                    "noise_mm": pb["noise_mm"],
                    "cv_scale": pb.get("cv_scale"),
                    "test_rmse_mm": res.metrics["after"]["test"]["rmse_mm"],
                    "train_rmse_mm": res.metrics["after"]["train"]["rmse_mm"],
                    "max_dh_length_error_mm": float(np.abs(dh).max()),
                    "time_s": time.perf_counter() - t0,
                }
            )
            print(
                f"seed {seed} {label:26s} noise {pb['noise_mm']:.3f} scale "
                f"{pb.get('cv_scale')} test {rows[-1]['test_rmse_mm']:.3f} mm, max DH "
                f"{rows[-1]['max_dh_length_error_mm']:.1f} mm, "
                f"{rows[-1]['time_s']:.0f} s",
                flush=True,
            )
    data = {"method": args.method, "runs": rows}
    lines = [
        f"# MAP prior weight on grouped hold-out ({args.method})",
        "",
        f"{len({r['seed'] for r in rows})} grouped splits, robust {args.robust}.",
        "",
        "| variant | mean noise_mm | mean test RMSE [mm] | worst [mm] | "
        "median max DH length error [mm] | mean time [s] |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for label in dict.fromkeys(r["variant"] for r in rows):
        sel = [r for r in rows if r["variant"] == label]
        scores = [r["test_rmse_mm"] for r in sel]
        lines.append(
            f"| {label} | {np.mean([r['noise_mm'] for r in sel]):.3f} | "
            f"{np.mean(scores):.3f} | {np.max(scores):.3f} | "
            f"{np.median([r['max_dh_length_error_mm'] for r in sel]):.1f} | "
            f"{np.mean([r['time_s'] for r in sel]):.0f} |"
        )
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "prior_weight.json").write_text(json.dumps(data, indent=1) + "\n")
    (args.out / "prior_weight.md").write_text("\n".join(lines) + "\n")
    return data


if __name__ == "__main__":
    main()
