"""Planning speed and accuracy: 40 poses on the built-in HSR JR680 model.

Times :func:`calib.planning.plan` end to end (candidates, Jacobians, base set, greedy plus
Fedorov exchange, ordering, and the summary with the random baseline), ``--runs`` times with
seeds ``0..runs-1``, and reports the median and the spread. The target is 5 s on the 2-core
build machine. A baseline measured in the same run (one forward pass plus Jacobian of the 5000
candidates) is reported next to it, since timings on a shared machine are noisy.

Accuracy (``--accuracy-seeds``, default 30): on EMULATED cells
(:mod:`calib.planning.emulated`: Table XII errors, σ 0.05 mm, anchor guess 30 mm off), the
aligned TCP RMS error of identify's default fit on 40 planned poses against the same-run
baseline of 3 × 40 random poses from the same feasible set, per seed, for the default TCP
criterion and for the D criterion alone; the issue's target is a ratio of means ≤ 0.5.

Writes ``bench/plan_results.json`` and ``bench/plan_results.md``. Run
``python -m bench.plan_bench [--runs 5] [--accuracy-seeds 30]``.
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path
from typing import Any

import numpy as np

from calib.cable import ParamLayout, length_jacobian
from calib.default_robot import DEFAULT_ROBOT_MODEL
from calib.models import builtin_model
from calib.planning import PlanOptions, plan
from calib.planning.emulated import emulated_trial, ratio_of_means

HERE = Path(__file__).resolve().parent
ANCHOR_MM = (1430.0, 330.0, 230.0)
TARGET_S = 5.0


def _baseline_s(n: int) -> float:
    """Time of one cable-length Jacobian over ``n`` random poses (the same-run yardstick)."""
    model = builtin_model(DEFAULT_ROBOT_MODEL)
    q = np.deg2rad(np.random.default_rng(0).uniform(-90, 90, size=(n, 6)))
    theta = np.zeros(ParamLayout(("A",)).size)
    theta[27:30] = ANCHOR_MM
    t0 = time.perf_counter()
    length_jacobian(model, theta, q, np.zeros(n, dtype=int))
    return time.perf_counter() - t0


def run(runs: int, n: int, candidates: int) -> dict[str, Any]:
    model = builtin_model(DEFAULT_ROBOT_MODEL)
    times, exchanges, tcp = [], [], []
    for seed in range(runs):
        t0 = time.perf_counter()
        result = plan(
            model, np.array(ANCHOR_MM), PlanOptions(n=n, candidates=candidates, seed=seed)
        )
        times.append(time.perf_counter() - t0)
        exchanges.append(result.exchanges)
        tcp.append((result.tcp.rms_mm, result.tcp_random["rms"]))
    median = float(np.median(times))
    return {
        "machine": {"python": platform.python_version(), "cpu_count": __import__("os").cpu_count()},
        "n_poses": n,
        "candidates": candidates,
        "runs": runs,
        "median_s": median,
        "min_s": float(np.min(times)),
        "max_s": float(np.max(times)),
        "target_s": TARGET_S,
        "within_target": median <= TARGET_S,
        "baseline_jacobian_s": float(np.median([_baseline_s(candidates) for _ in range(5)])),
        "exchanges": exchanges,
        "tcp_sigma_rms_mm": {"plan": [t[0] for t in tcp], "random": [t[1] for t in tcp]},
    }


def accuracy(seeds: int, n: int) -> dict[str, Any]:
    """Planned vs random on ``seeds`` emulated cells, per criterion (see the docstring)."""
    model = builtin_model(DEFAULT_ROBOT_MODEL)
    out: dict[str, Any] = {"seeds": seeds, "n_poses": n, "random_designs": 3}
    for criterion in ("tcp", "d"):
        trials = [
            emulated_trial(model, seed, PlanOptions(n=n, seed=seed, criterion=criterion))
            for seed in range(seeds)
        ]
        planned = np.array([t.planned_mm for t in trials])
        random_ = np.array([t.random_mean_mm for t in trials])
        out[criterion] = {
            "planned_mm": planned.tolist(),
            "random_mm": random_.tolist(),
            "predicted_planned_mm": [t.predicted_planned_mm for t in trials],
            "predicted_random_mm": [t.predicted_random_mm for t in trials],
            "ratio_of_means": ratio_of_means(trials),
            "ratio_first_5": ratio_of_means(trials[:5]),
            "ratio_blocks_of_5": [
                ratio_of_means(trials[i : i + 5]) for i in range(0, seeds - 4, 5)
            ],
            "planned_better": int(np.count_nonzero(planned < random_)),
            "ratio_ci90_bootstrap": _bootstrap_ci90(planned, random_),
        }
    return out


def _bootstrap_ci90(planned: np.ndarray, random_: np.ndarray) -> list[float]:
    """5th and 95th percentile of the ratio of means over 4000 seed resamples (seeded)."""
    rng = np.random.default_rng(0)
    idx = rng.integers(0, planned.size, size=(4000, planned.size))
    ratios = planned[idx].mean(axis=1) / random_[idx].mean(axis=1)
    return [float(v) for v in np.percentile(ratios, [5, 95])]


def _accuracy_markdown(acc: dict[str, Any]) -> list[str]:
    lines = [
        "## Planned against random poses (EMULATED cells)",
        "",
        f"Seeds 0..{acc['seeds'] - 1}; identify defaults with method LM (MAP prior toward the "
        "nominal model, noise estimated); aligned TCP RMS error [mm] at "
        f"500 held-out workspace poses; random = mean of {acc['random_designs']} random "
        f"designs of {acc['n_poses']} poses per seed (same limits, stroke, floor).",
        "",
        "| criterion | planned | random | ratio of means (90 % bootstrap) | seeds 0..4 | "
        "blocks of 5 (min–max) | planned better | predicted planned / random |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for crit in ("tcp", "d"):
        r = acc[crit]
        blocks, ci = r["ratio_blocks_of_5"], r["ratio_ci90_bootstrap"]
        pp, pr = np.mean(r["predicted_planned_mm"]), np.mean(r["predicted_random_mm"])
        lines.append(
            f"| {crit} | {np.mean(r['planned_mm']):.4f} | {np.mean(r['random_mm']):.4f} | "
            f"{r['ratio_of_means']:.3f} ({ci[0]:.2f}–{ci[1]:.2f}) | {r['ratio_first_5']:.3f} | "
            f"{min(blocks):.2f}–{max(blocks):.2f} | {r['planned_better']}/{acc['seeds']} | "
            f"{pp:.4f} / {pr:.4f} = {pp / pr:.3f} |"
        )
    r = acc["tcp"]
    lines += ["", "Per seed, TCP criterion (planned / random mm):", ""]
    lines.append(
        ", ".join(
            f"{i}: {p:.4f}/{q:.4f}"
            for i, (p, q) in enumerate(zip(r["planned_mm"], r["random_mm"], strict=True))
        )
    )
    return [*lines, ""]


def to_markdown(res: dict[str, Any]) -> str:
    tcp = res["tcp_sigma_rms_mm"]
    return "\n".join(
        [
            "# Planning speed",
            "",
            f"{res['n_poses']} poses from {res['candidates']} candidates, HSR JR680, "
            f"{res['runs']} runs (seeds 0..{res['runs'] - 1}).",
            "",
            "| median [s] | min [s] | max [s] | target [s] | same-run baseline: one Jacobian [s] |",
            "|---|---|---|---|---|",
            f"| {res['median_s']:.2f} | {res['min_s']:.2f} | {res['max_s']:.2f} | "
            f"{res['target_s']:.1f} | {res['baseline_jacobian_s']:.4f} |",
            "",
            f"Predicted aligned TCP σ (RMS, noise 0.05 mm): plan {np.mean(tcp['plan']):.3f} mm, "
            f"random poses {np.mean(tcp['random']):.3f} mm (mean over runs).",
            "",
            *(_accuracy_markdown(res["accuracy"]) if "accuracy" in res else []),
        ]
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5)
    parser.add_argument("--n", type=int, default=40)
    parser.add_argument("--candidates", type=int, default=5000)
    parser.add_argument("--accuracy-seeds", type=int, default=30, help="0: speed only")
    args = parser.parse_args()
    res = run(args.runs, args.n, args.candidates)
    if args.accuracy_seeds >= 5:
        res["accuracy"] = accuracy(args.accuracy_seeds, args.n)
    (HERE / "plan_results.json").write_text(json.dumps(res, indent=2) + "\n")
    (HERE / "plan_results.md").write_text(to_markdown(res))
    print(to_markdown(res))


if __name__ == "__main__":
    main()
