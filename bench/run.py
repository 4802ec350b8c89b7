"""`make bench`: identification speed and accuracy per method against a naive baseline.

For n = 100, 500 and 2000 poses of an emulated cell (Table XII D1 errors, σ = 0.05 mm noise,
seeded), every method identifies the model; in the same run a naive
``scipy.optimize.least_squares`` with a 2-point finite-difference Jacobian solves the same
residual on the same free parameters from the same start. Accuracy is the RMSE of the
identified model against the *true* lengths of 200 held-out poses. Results go to
``bench/results.json`` and ``bench/results.md``. The indicator poll-rate benchmark
(``bench/indicator_bench.py``) is appended when present.
"""

from __future__ import annotations

import json
import platform
import time
from pathlib import Path
from typing import Any

import numpy as np
from scipy.optimize import least_squares

from calib.cable import predict_lengths
from calib.dataset import make_samples
from calib.identify import METHODS, IdentifyOptions, identify
from calib.models import builtin_model
from calib.problem import Problem
from calib.synthetic import make_true_cell, random_poses_deg

OUT = Path(__file__).parent
SIZES = (100, 500, 2000)
N_TEST = 200
NOISE_MM = 0.05
DE_MAX_N = 500  # DE at n = 2000 takes minutes; it is a baseline, timed up to n = 500


def _case(n: int, seed: int = 0) -> tuple[Any, Any, Any, Any, Any]:
    model = builtin_model("hsr-jr680")
    cell = make_true_cell(model)
    rng = np.random.default_rng(seed)
    q = random_poses_deg(cell, n + N_TEST, rng)
    clean = cell.lengths_mm(q)
    noisy = clean + rng.normal(0, NOISE_MM, clean.shape)
    return model, q, clean, make_samples(q, noisy), np.arange(n)


def _truth_rmse(model: Any, theta: Any, q: Any, clean: Any, test: Any) -> float:
    pred = predict_lengths(model, theta, np.deg2rad(q[test]), np.zeros(test.size, dtype=int))
    return float(np.sqrt(np.mean((pred - clean[test]) ** 2)))


def _naive(problem: Problem) -> tuple[Any, float]:
    t0 = time.perf_counter()
    res = least_squares(problem.residuals, problem.x0(), jac="2-point", method="trf",
                        max_nfev=20000)  # fmt: skip
    return problem.full(res.x), time.perf_counter() - t0


def run_identification() -> list[dict[str, Any]]:
    rows: list[dict[str, Any]] = []
    for n in SIZES:
        model, q, clean, samples, train = _case(n)
        test = np.arange(n, n + N_TEST)
        baseline_problem: Problem | None = None
        for method in METHODS:
            if method == "de" and n > DE_MAX_N:
                continue
            opts = IdentifyOptions(method=method)  # type: ignore[arg-type]
            t0 = time.perf_counter()
            res = identify(model, samples, opts, train_rows=train, test_rows=test)
            elapsed = time.perf_counter() - t0
            rows.append({
                "n": n, "method": method, "time_s": elapsed,
                "solver_time_s": res.solver.elapsed_s, "iterations": res.solver.iterations,
                "heldout_rmse_vs_truth_mm": _truth_rmse(model, res.theta, q, clean, test),
                "status": res.solver.status,
            })  # fmt: skip
            print(f"n={n:5d} {method:9s} {elapsed:8.3f} s  "
                  f"rmse {rows[-1]['heldout_rmse_vs_truth_mm']:.4f} mm", flush=True)  # fmt: skip
            if method == "ukf-vslm":
                free = np.array([nm in res.free_names for nm in res.layout.names])
                baseline_problem = Problem(
                    model, res.layout, np.deg2rad(q[train]), samples.length_mm[train],
                    np.zeros(train.size, dtype=int), free, res.theta_before,
                )  # fmt: skip
        assert baseline_problem is not None
        # Same start as the methods: nominal DH with the tool and anchor fitted.
        start = identify(model, samples, IdentifyOptions(method="lm"), train_rows=train,
                         test_rows=test)  # fmt: skip
        theta0 = start.theta.copy()
        theta0[:24] = 0.0
        theta_naive, t_naive = _naive(baseline_problem.with_theta0(theta0))
        rows.append({
            "n": n, "method": "naive-least_squares-fd", "time_s": t_naive,
            "solver_time_s": t_naive, "iterations": None,
            "heldout_rmse_vs_truth_mm": _truth_rmse(model, theta_naive, q, clean, test),
            "status": None,
        })  # fmt: skip
        print(f"n={n:5d} naive     {t_naive:8.3f} s  "
              f"rmse {rows[-1]['heldout_rmse_vs_truth_mm']:.4f} mm", flush=True)  # fmt: skip
    return rows


def _markdown(rows: list[dict[str, Any]], checks: dict[str, Any], extra: dict[str, Any]) -> str:
    lines = [
        "# Benchmark results",
        "",
        f"Machine: {platform.processor() or platform.machine()}, Python "
        f"{platform.python_version()}. Emulated cell, σ = {NOISE_MM} mm, {N_TEST} held-out "
        "poses, RMSE against the true lengths.",
        "",
        "| n | method | time [s] | iterations | held-out RMSE vs truth [mm] |",
        "|---:|---|---:|---:|---:|",
    ]
    for r in rows:
        it = "" if r["iterations"] is None else str(r["iterations"])
        lines.append(f"| {r['n']} | {r['method']} | {r['time_s']:.3f} | {it} | "
                     f"{r['heldout_rmse_vs_truth_mm']:.4f} |")  # fmt: skip
    lines += ["", "## Targets", "", "| check | measured | target | met |", "|---|---:|---:|---|"]
    for key, value in checks.items():
        lines.append(f"| {key} | {value['measured']:.3f} | {value['target']} | {value['met']} |")
    if extra:
        lines += ["", "## Indicator link", "", "```", json.dumps(extra, indent=2), "```"]
    return "\n".join(lines) + "\n"


def main() -> None:
    rows = run_identification()

    def get(n: int, method: str) -> dict[str, Any]:
        return next(r for r in rows if r["n"] == n and r["method"] == method)

    checks: dict[str, Any] = {}
    t100, t2000 = get(100, "ukf-vslm")["time_s"], get(2000, "ukf-vslm")["time_s"]
    checks["ukf-vslm_100_s"] = {"measured": t100, "target": "<= 0.05"}
    checks["ukf-vslm_2000_s"] = {"measured": t2000, "target": "<= 1.0"}
    for n in SIZES:
        naive, ours = get(n, "naive-least_squares-fd"), get(n, "ukf-vslm")
        checks[f"speedup_vs_naive_n{n}"] = {"measured": naive["time_s"] / ours["time_s"],
                                            "target": ">= 50"}  # fmt: skip
        checks[f"accuracy_ratio_vs_naive_n{n}"] = {
            "measured": ours["heldout_rmse_vs_truth_mm"] / naive["heldout_rmse_vs_truth_mm"],
            "target": "<= 1.0",
        }
    for value in checks.values():
        bound = float(value["target"].split()[-1])
        value["met"] = (value["measured"] <= bound) if "<=" in value["target"] else (
            value["measured"] >= bound)  # fmt: skip
    extra: dict[str, Any] = {}
    try:
        from bench import indicator_bench

        extra = indicator_bench.run()
    except ImportError:
        extra = {}
    except Exception as exc:  # the identification numbers are still worth writing
        extra = {"error": repr(exc)}
    result = {"identification": rows, "checks": checks, "indicator": extra}
    (OUT / "results.json").write_text(json.dumps(result, indent=2) + "\n", encoding="utf-8")
    (OUT / "results.md").write_text(_markdown(rows, checks, extra), encoding="utf-8")
    print(f"wrote {OUT / 'results.json'} and {OUT / 'results.md'}")


if __name__ == "__main__":
    main()
