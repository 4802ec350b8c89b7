"""Solver speed and final cost on the bundled real data (issue 10, goal 1).

Problems are built the way :func:`calib.identify.identify` builds them (maximum likelihood, no
robust weights): anchors fitted with the nominal model, tool point and anchors refitted, base
parameter set from the identifiability analysis (:func:`build_problem`). Then, for

* ``n = 100``: the training rows of the paper protocol's draws, seeds 0–9
  (:func:`calib.protocol.paper_split`; the 20 held-out rows give a test RMSE), and
* ``n = 2017``: every row (no test set),

each method (``geolm``, ``ukf-vslm``, ``lm`` through identify's own dispatch, and scipy
``least_squares`` with its default tolerances) is timed (median of ``--repeats`` runs, solver
only, after the common start-up), with iterations, status, final cost over the reference cost,
and the test RMSE.

**Reference cost.** A long scipy ``least_squares`` run (trf, ``x_scale='jac'``, all tolerances
1e-15, ``--ref-nfev`` evaluations). The run records the best cost against wall time, so the
same run gives the time it needs to come within 1 % of its own final cost. On these data the
cost has no minimiser (see :mod:`calib.solvers.geolm`): the reference is the lowest cost found
in the budget, not an optimum, and a longer budget lowers it a little further. Results are
cached in ``bench/solver_real_reference.json`` keyed by problem and budget; ``--recompute``
ignores the cache.

Also the paper protocol (120 random rows, 100/20, ``--splits`` seeds) for ``geolm`` and
``ukf-vslm``: mean and worst test RMSE.

Writes ``bench/solver_real.json`` and ``bench/solver_real.md``. Run
``python -m bench.solver_real`` (``--quick``: 2 subsets, 4 splits, small reference budget).
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from scipy.optimize import least_squares

from bench.real_data import ROBOT
from calib import methods
from calib.cable import N_DH, ParamLayout, length_jacobian, predict_lengths
from calib.dataset import SampleSet
from calib.identifiability import analyse
from calib.identify import IdentifyOptions, _fit, _generic_jacobian, fit_anchors
from calib.kinematics import FloatArray
from calib.models import RobotModel
from calib.problem import Problem
from calib.protocol import paper_split
from calib.solvers import geolm
from calib.solvers.common import SolverResult
from daemon.datafiles import load_robot, read_samples

OUT = Path(__file__).parent
REFERENCE_CACHE = OUT / "solver_real_reference.json"
METHODS = ("geolm", "ukf-vslm", "lm", "scipy")


def build_problem(model: RobotModel, samples: SampleSet, rows: np.ndarray) -> Problem:
    """The ML problem identify() solves on ``rows`` (steps 2–4 of its docstring, defaults)."""
    sub = samples.subset(rows)
    layout = ParamLayout(samples.anchor_ids)
    q, aidx, length = np.deg2rad(sub.joints_deg), sub.anchor_index(), sub.length_mm
    before = fit_anchors(model, layout, np.zeros(layout.size), q, aidx, length)
    free0 = np.zeros(layout.size, dtype=bool)
    free0[N_DH:] = True
    start = _fit(Problem(model, layout, q, length, aidx, free0, before))
    _, jac = length_jacobian(model, start, q, aidx)
    ident = analyse(jac, layout.names, np.ones(layout.size, dtype=bool),
                    rtol=IdentifyOptions().rtol,
                    structural_jacobian=_generic_jacobian(model, layout, start))  # fmt: skip
    free = np.array([n in ident.base for n in layout.names])
    return Problem(model, layout, q, length, aidx, free, start)


def scipy_solve(problem: Problem, tol: float = 1e-8, max_nfev: int | None = None) -> SolverResult:
    """scipy ``least_squares`` (trf, analytic Jacobian, ``x_scale='jac'``) as a SolverResult."""
    t0 = time.perf_counter()
    res = least_squares(problem.residuals, problem.x0(),
                        jac=lambda x: problem.residuals_and_jacobian(x)[1], method="trf",
                        x_scale="jac", ftol=tol, xtol=tol, gtol=tol, max_nfev=max_nfev)  # fmt: skip
    return SolverResult("scipy", res.x, bool(res.status > 0), int(res.status), str(res.message),
                        int(res.nfev), [], time.perf_counter() - t0)  # fmt: skip


def reference_run(problem: Problem, max_nfev: int) -> dict[str, Any]:
    """Long tight scipy run: final cost, and the time its best cost first came within 1 %."""
    trace: list[tuple[float, float]] = []  # (elapsed_s, cost)
    t0 = time.perf_counter()

    def residuals(x: FloatArray) -> FloatArray:
        r = problem.residuals(x)
        trace.append((time.perf_counter() - t0, 0.5 * float(r @ r)))
        return r

    res = least_squares(residuals, problem.x0(),
                        jac=lambda x: problem.residuals_and_jacobian(x)[1], method="trf",
                        x_scale="jac", ftol=1e-15, xtol=1e-15, gtol=1e-15,
                        max_nfev=max_nfev)  # fmt: skip
    best = float(res.cost)
    within = next(t for t, c in trace if c <= 1.01 * best)
    return {"cost": best, "nfev": int(res.nfev), "status": int(res.status),
            "time_s": time.perf_counter() - t0, "time_to_1pct_s": float(within)}  # fmt: skip


def _solver(method: str) -> Callable[[Problem], SolverResult]:
    if method == "geolm":
        return lambda p: geolm.solve(p)
    if method == "scipy":
        return scipy_solve
    opts = IdentifyOptions(method=method)  # type: ignore[arg-type]
    return lambda p: methods.run(p, p.x0(), opts, None)


def test_rmse_mm(problem: Problem, x: FloatArray, samples: SampleSet, rows: np.ndarray) -> float:
    """RMSE of ``L_model − L`` on ``rows`` of ``samples`` [mm]."""
    pred = predict_lengths(problem.model, problem.full(x), np.deg2rad(samples.joints_deg[rows]),
                           samples.anchor_index()[rows])  # fmt: skip
    return float(np.sqrt(np.mean((pred - samples.length_mm[rows]) ** 2)))


def _case(
    label: str, problem: Problem, reference: dict[str, Any], repeats: int,
    test: tuple[SampleSet, np.ndarray] | None,
) -> list[dict[str, Any]]:  # fmt: skip
    out = []
    for m in METHODS:
        run = _solver(m)
        times, res = [], None
        for _ in range(repeats):
            t0 = time.perf_counter()
            res = run(problem)
            times.append(time.perf_counter() - t0)
        assert res is not None
        cost = problem.cost(res.x)
        rec: dict[str, Any] = {
            "case": label, "method": m, "n": problem.n_samples,
            "time_s": float(np.median(times)), "iterations": res.iterations,
            "status": res.status, "converged": res.success, "cost": cost,
            "cost_ratio": cost / reference["cost"],
            "test_rmse_mm": test_rmse_mm(problem, res.x, *test) if test else None,
        }  # fmt: skip
        print(f"{label:10s} {m:9s} {rec['time_s']:.3f} s it {res.iterations:4d} "
              f"status {res.status} cost/ref {rec['cost_ratio']:.4f}", flush=True)  # fmt: skip
        out.append(rec)
    return out


def _reference(key: str, problem: Problem, nfev: int, cache: dict[str, Any], redo: bool
               ) -> dict[str, Any]:  # fmt: skip
    full_key = f"{key}/nfev={nfev}"
    if redo or full_key not in cache:
        cache[full_key] = reference_run(problem, nfev)
        print(f"reference {full_key}: cost {cache[full_key]['cost']:.5f} "
              f"({cache[full_key]['time_s']:.1f} s)", flush=True)  # fmt: skip
    ref: dict[str, Any] = cache[full_key]
    return ref


def paper_protocol(model: RobotModel, samples: SampleSet, seeds: range) -> dict[str, Any]:
    """Mean and worst test RMSE of geolm and ukf-vslm over paper-protocol draws."""
    rmse: dict[str, list[float]] = {"geolm": [], "ukf-vslm": []}
    for s in seeds:
        train, test = paper_split(len(samples), s)
        problem = build_problem(model, samples, train)
        for m in rmse:
            rmse[m].append(test_rmse_mm(problem, _solver(m)(problem).x, samples, test))
        print(f"paper protocol seed {s}: geolm {rmse['geolm'][-1]:.3f} "
              f"ukf-vslm {rmse['ukf-vslm'][-1]:.3f} mm", flush=True)  # fmt: skip
    return {m: {"mean_mm": float(np.mean(v)), "max_mm": float(np.max(v)), "per_seed_mm": v}
            for m, v in rmse.items()}  # fmt: skip


def main(argv: list[str] | None = None) -> dict[str, Any]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--recompute", action="store_true", help="ignore the reference cache")
    parser.add_argument("--ref-nfev", type=int, default=20000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--subsets", type=int, default=10)
    parser.add_argument("--splits", type=int, default=20)
    parser.add_argument("--no-full", action="store_true", help="skip the n = 2017 case")
    parser.add_argument("--out", type=Path, default=OUT)
    args = parser.parse_args(argv)
    if args.quick:
        args.subsets, args.splits, args.ref_nfev, args.repeats = 2, 4, 500, 1
    model, samples = load_robot(ROBOT), read_samples(None)
    cache: dict[str, Any] = (json.loads(REFERENCE_CACHE.read_text())
                             if REFERENCE_CACHE.exists() else {})  # fmt: skip
    rows: list[dict[str, Any]] = []
    refs: dict[str, Any] = {}
    for s in range(args.subsets):
        train, test = paper_split(len(samples), s)
        problem = build_problem(model, samples, train)
        ref = _reference(f"n100/seed{s}", problem, args.ref_nfev, cache, args.recompute)
        refs[f"n100/seed{s}"] = ref
        rows += _case(f"n100/s{s}", problem, ref, args.repeats, (samples, test))
    if not args.no_full:
        problem = build_problem(model, samples, np.arange(len(samples)))
        ref = _reference("n2017", problem, args.ref_nfev, cache, args.recompute)
        refs["n2017"] = ref
        rows += _case("n2017", problem, ref, max(1, args.repeats // 2), None)
    REFERENCE_CACHE.write_text(json.dumps(cache, indent=1) + "\n")
    data = {"machine": f"{platform.machine()}, Python {platform.python_version()}",
            "ref_nfev": args.ref_nfev, "references": refs, "runs": rows,
            "paper_protocol": paper_protocol(model, samples, range(args.splits))}  # fmt: skip
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "solver_real.json").write_text(json.dumps(data, indent=1) + "\n")
    (args.out / "solver_real.md").write_text(markdown(data))
    return data


def markdown(data: dict[str, Any]) -> str:
    """The tables of ``solver_real.md``."""
    lines = ["# Solvers on the bundled real data (issue 10)", "",
             f"Machine: {data['machine']}. Reference: scipy least_squares, tolerances 1e-15, "
             f"{data['ref_nfev']} evaluations. Generated by `python -m bench.solver_real`.", "",
             "## Per method (n = 100: mean over subsets; time: median of repeats, then mean)", "",
             "cost / ref: over the reference run's cost; cost / best: over the lowest cost "
             "any method or the reference reached on that problem.", "",
             "| n | method | time [s] | iterations | converged | cost / ref (mean) | "
             "cost / ref (worst) | cost / best (mean) | cost / best (worst) | test RMSE [mm] |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|"]  # fmt: skip
    runs = data["runs"]
    best: dict[str, float] = {}
    for r in runs:  # the lowest cost any method or the reference reached, per problem
        ref = data["references"][r["case"].replace("/s", "/seed")]["cost"]
        best[r["case"]] = min(best.get(r["case"], ref), r["cost"])
    for n in sorted({r["n"] for r in runs}):
        for m in METHODS:
            sel = [r for r in runs if r["n"] == n and r["method"] == m]
            test = [r["test_rmse_mm"] for r in sel if r["test_rmse_mm"] is not None]
            ratios = [r["cost_ratio"] for r in sel]
            to_best = [r["cost"] / best[r["case"]] for r in sel]
            lines.append(
                f"| {n} | {m} | {np.mean([r['time_s'] for r in sel]):.3f} | "
                f"{np.mean([r['iterations'] for r in sel]):.0f} | "
                f"{sum(r['converged'] for r in sel)}/{len(sel)} | {np.mean(ratios):.4f} | "
                f"{np.max(ratios):.4f} | {np.mean(to_best):.4f} | {np.max(to_best):.4f} | "
                + (f"{np.mean(test):.3f} |" if test else "– |")
            )
    lines += ["", "## Reference runs", "", "| problem | cost [mm²] | evaluations | time [s] | "
              "time to within 1 % [s] |", "|---|---:|---:|---:|---:|"]  # fmt: skip
    for key, ref in data["references"].items():
        lines.append(f"| {key} | {ref['cost']:.5f} | {ref['nfev']} | {ref['time_s']:.1f} | "
                     f"{ref['time_to_1pct_s']:.2f} |")  # fmt: skip
    pp = data["paper_protocol"]
    lines += ["", "## Paper protocol (100/20 random rows)", "", "| method | mean test RMSE [mm] | "
              "worst [mm] |", "|---|---:|---:|"]  # fmt: skip
    lines += [f"| {m} | {v['mean_mm']:.3f} | {v['max_mm']:.3f} |" for m, v in pp.items()]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
