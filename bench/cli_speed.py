"""The speed an operator feels at the command line: ``cablecal identify`` against its floor.

Measured in one run, interleaved so that the load of a shared machine falls on every figure
alike (each round runs each command once, in turn):

* ``floor``: ``python -c "import numpy, scipy.linalg"``, the import floor of any identify;
* ``identify_100``: ``cablecal identify`` on the first 100 rows of the bundled real data
  (calib/data/hsr-robotcali.csv, the paper's D1), the whole command (start, imports, fit,
  table, result.json), wall time;
* ``identify_100_cold``: the same command on a copy of the sources with no cached bytecode
  (and none written): what a start costs where the modules were never byte-compiled;
* ``elapsed_100`` / ``elapsed_2017``: identify's own ``elapsed_s`` from ``result.json`` of the
  100-row run and of a run on all 2017 rows;
* ``bare`` and ``help``: ``python -c pass`` (a bare Python start) and ``cablecal --help`` (the
  installed console script): what the command line costs before any command runs.

On a shared machine wall time follows the load, so CPU time is measured as well: of each
child process (``getrusage`` of the children, user + system) and, for identify's own part,
``time.process_time`` around :func:`calib.identify.identify` in this process with one BLAS
thread (the CLI's setting), on the same rows.

Targets (issue 20): ``identify_100 / floor`` at most 1.5; ``elapsed_100`` at most 0.05 s;
``elapsed_2017`` at most 0.1 s; (issue 26) ``help`` at most 0.3 s over ``bare``. Medians over
``--runs`` rounds, with the minimum (the figure least disturbed by other processes) next to
it, and the load average at the start and the end of the run. The top-level imports of one
``python -X importtime`` run of the 100-row command list what the command still loads beyond
the floor.

Writes ``bench/cli_speed.json`` and ``bench/cli_speed.md``. Run
``python -m bench.cli_speed [--runs 7]``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from calib.default_robot import DEFAULT_ROBOT_MODEL

HERE = Path(__file__).resolve().parent
DATA = HERE.parent / "calib" / "data" / "hsr-robotcali.csv"
TARGETS = {"ratio_100": 1.5, "elapsed_100_s": 0.05, "elapsed_2017_s": 0.1}
#: ``cablecal --help`` over a bare Python start, at most [s] (issue 26).
HELP_OVER_BARE_S = 0.3
#: Import-time entries listed in the report: cumulative at least this long [us].
IMPORT_LIST_US = 20_000
#: The project's packages (what ``make bytecode`` compiles; the cold figure runs them uncompiled).
PACKAGES = ("calib", "daemon", "drivers", "simulator")


def _cli(csv: Path, out: Path) -> list[str]:
    return [sys.executable, "-m", "daemon.cli", "identify", str(csv), "--out", str(out)]


def _source_copy(tmp: Path) -> Path:
    """The project's packages copied to ``tmp/src`` without any cached bytecode."""
    dst = tmp / "src"
    for pkg in PACKAGES:
        shutil.copytree(HERE.parent / pkg, dst / pkg, ignore=shutil.ignore_patterns("__pycache__"))
    return dst


def _wall(
    cmd: list[str], cwd: Path | None = None, env: dict[str, str] | None = None
) -> tuple[float, float]:
    """Wall and CPU (user + system) time [s] of one run of ``cmd``."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(
        cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=cwd, env=env
    )
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu


def _identify_cpu(rows: int) -> float:
    """``time.process_time`` [s] of one default identify on the first ``rows`` rows."""
    import numpy as np

    from calib.identify import identify
    from calib.models import builtin_model
    from daemon.datafiles import read_samples

    samples = read_samples(None)
    part = samples.subset(np.arange(min(rows, len(samples.length_mm))))
    t0 = time.process_time()
    identify(builtin_model(DEFAULT_ROBOT_MODEL), part)
    return time.process_time() - t0


def _elapsed(result_json: Path) -> float:
    return float(json.loads(result_json.read_text(encoding="utf-8"))["elapsed_s"])


def _top_imports(cmd: list[str]) -> list[tuple[str, float]]:
    """Top-level modules (and their direct children) of one ``-X importtime`` run, with
    their cumulative time [ms], longest first."""
    proc = subprocess.run(
        [cmd[0], "-X", "importtime", *cmd[1:]], capture_output=True, text=True, check=True
    )
    out: list[tuple[str, float]] = []
    for line in proc.stderr.splitlines():
        if not line.startswith("import time:") or "cumulative" in line:
            continue
        _, cumulative, name = line.split("|")
        depth = (len(name) - len(name.lstrip(" "))) // 2
        if depth <= 1 and int(cumulative) >= IMPORT_LIST_US:
            out.append((name.strip(), int(cumulative) / 1000.0))
    return sorted(out, key=lambda kv: -kv[1])


def main(argv: list[str] | None = None) -> dict[str, Any]:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=7)
    args = ap.parse_args(argv)
    rows = DATA.read_text(encoding="utf-8").splitlines()
    floor_cmd = [sys.executable, "-c", "import numpy, scipy.linalg"]
    bare_cmd = [sys.executable, "-c", "pass"]
    help_cmd = [str(Path(sys.executable).parent / "cablecal"), "--help"]
    load_start = os.getloadavg()
    from daemon.process.blas import single_threaded_blas

    single_threaded_blas()
    walls: dict[str, list[float]] = {
        "floor": [],
        "identify_100": [],
        "identify_100_cold": [],
        "bare": [],
        "help": [],
    }
    cpus: dict[str, list[float]] = {"floor": [], "identify_100": [], "bare": [], "help": []}
    elapsed: dict[str, list[float]] = {
        "elapsed_100_s": [],
        "elapsed_2017_s": [],
        "cpu_100_s": [],
        "cpu_2017_s": [],
    }
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        small = tmp / "first-100.csv"
        small.write_text("\n".join(rows[:101]) + "\n", encoding="utf-8")
        out_small, out_all = tmp / "r100.json", tmp / "r2017.json"
        _identify_cpu(100)  # imports and caches, as the CLI pays them in the wall figure
        # The cold figure: the same command on a copy of the sources with no bytecode cached
        # (and none written), as after an editable install where PYTHONDONTWRITEBYTECODE is set.
        src = _source_copy(tmp)
        cold_env = {**os.environ, "PYTHONDONTWRITEBYTECODE": "1"}
        for _ in range(args.runs):
            walls["identify_100_cold"].append(_wall(_cli(small, out_small), src, cold_env)[0])
            for key, cmd in (
                ("floor", floor_cmd),
                ("identify_100", _cli(small, out_small)),
                ("bare", bare_cmd),
                ("help", help_cmd),
            ):
                wall, cpu = _wall(cmd)
                walls[key].append(wall)
                cpus[key].append(cpu)
            elapsed["elapsed_100_s"].append(_elapsed(out_small))
            _wall(_cli(DATA, out_all))
            elapsed["elapsed_2017_s"].append(_elapsed(out_all))
            elapsed["cpu_100_s"].append(_identify_cpu(100))
            elapsed["cpu_2017_s"].append(_identify_cpu(len(rows) - 1))
        imports = _top_imports(_cli(small, out_small))
    med = {k: statistics.median(v) for k, v in {**walls, **elapsed}.items()}
    low = {k: min(v) for k, v in {**walls, **elapsed}.items()}
    cpu_med = {k: statistics.median(v) for k, v in cpus.items()}
    figures = {
        "ratio_100": med["identify_100"] / med["floor"],
        "ratio_100_cold": med["identify_100_cold"] / med["floor"],
        "elapsed_100_s": med["elapsed_100_s"],
        "elapsed_2017_s": med["elapsed_2017_s"],
    }
    cpu_figures = {
        "ratio_100": cpu_med["identify_100"] / cpu_med["floor"],
        "elapsed_100_s": med["cpu_100_s"],
        "elapsed_2017_s": med["cpu_2017_s"],
    }
    best = {
        "ratio_100": low["identify_100"] / low["floor"],
        "ratio_100_cold": low["identify_100_cold"] / low["floor"],
        "elapsed_100_s": low["elapsed_100_s"],
        "elapsed_2017_s": low["elapsed_2017_s"],
    }
    report: dict[str, Any] = {
        "runs": args.runs,
        "machine": f"{platform.machine()}, {os.cpu_count()} cpus",
        "load_average": {"start": list(load_start), "end": list(os.getloadavg())},
        "python": platform.python_version(),
        "median_s": med,
        "min_s": low,
        "figures": figures,
        "figures_at_min": best,
        "cpu_median_s": cpu_med,
        "figures_cpu": cpu_figures,
        "targets": TARGETS,
        "met": {k: figures[k] <= TARGETS[k] for k in TARGETS},
        "met_cold": figures["ratio_100_cold"] <= TARGETS["ratio_100"],
        "met_cpu": {k: cpu_figures[k] <= TARGETS[k] for k in TARGETS},
        "top_imports_ms": imports,
        "help_over_bare_s": {
            "wall": med["help"] - med["bare"],
            "wall_at_min": low["help"] - low["bare"],
            "cpu": cpu_med["help"] - cpu_med["bare"],
            "target": HELP_OVER_BARE_S,
            "met": med["help"] - med["bare"] <= HELP_OVER_BARE_S,
        },
    }
    (HERE / "cli_speed.json").write_text(json.dumps(report, indent=2) + "\n", encoding="utf-8")
    (HERE / "cli_speed.md").write_text(_markdown(report), encoding="utf-8")
    print(_markdown(report))
    return report


def _load(values: list[float]) -> str:
    return ", ".join(f"{v:.1f}" for v in values)


def _markdown(r: dict[str, Any]) -> str:
    med, low, fig, best = r["median_s"], r["min_s"], r["figures"], r["figures_at_min"]
    cpu, cfig, h = r["cpu_median_s"], r["figures_cpu"], r["help_over_bare_s"]
    lines = [
        "# CLI speed: `cablecal identify` against the import floor",
        "",
        f"Written by `python -m bench.cli_speed` ({r['runs']} interleaved rounds; "
        f"{r['machine']}, Python {r['python']}; load average (1, 5, 15 min) at the start "
        f"{_load(r['load_average']['start'])}, at the end {_load(r['load_average']['end'])}). "
        "Data: the bundled real data (D1).",
        "",
        "| figure | median | min | target | met (median) |",
        "|---|---|---|---|---|",
        f"| floor `import numpy, scipy.linalg` [s] | {med['floor']:.3f} | {low['floor']:.3f} | | |",
        f"| `cablecal identify`, 100 rows, wall [s] | {med['identify_100']:.3f} | "
        f"{low['identify_100']:.3f} | | |",
        f"| ratio identify / floor | {fig['ratio_100']:.2f} | {best['ratio_100']:.2f} | "
        f"<= {TARGETS['ratio_100']} | {'yes' if r['met']['ratio_100'] else 'no'} |",
        f"| `cablecal identify`, 100 rows, no cached bytecode, wall [s] | "
        f"{med['identify_100_cold']:.3f} | {low['identify_100_cold']:.3f} | | |",
        f"| ratio identify (no cached bytecode) / floor | {fig['ratio_100_cold']:.2f} | "
        f"{best['ratio_100_cold']:.2f} | <= {TARGETS['ratio_100']} | "
        f"{'yes' if r['met_cold'] else 'no'} |",
        f"| identify's own elapsed, 100 rows [s] | {fig['elapsed_100_s']:.3f} | "
        f"{best['elapsed_100_s']:.3f} | <= {TARGETS['elapsed_100_s']} | "
        f"{'yes' if r['met']['elapsed_100_s'] else 'no'} |",
        f"| identify's own elapsed, 2017 rows [s] | {fig['elapsed_2017_s']:.3f} | "
        f"{best['elapsed_2017_s']:.3f} | <= {TARGETS['elapsed_2017_s']} | "
        f"{'yes' if r['met']['elapsed_2017_s'] else 'no'} |",
        "",
        "`cablecal --help` against a bare Python start (`python -c pass`), in the same rounds:",
        "",
        "| figure | median | min | target | met (median) |",
        "|---|---|---|---|---|",
        f"| bare start `python -c pass`, wall [s] | {med['bare']:.3f} | {low['bare']:.3f} | | |",
        f"| `cablecal --help`, wall [s] | {med['help']:.3f} | {low['help']:.3f} | | |",
        f"| `--help` over the bare start, wall [s] | {h['wall']:.3f} | {h['wall_at_min']:.3f} | "
        f"<= {h['target']} | {'yes' if h['met'] else 'no'} |",
        f"| `--help` over the bare start, CPU [s] | {h['cpu']:.3f} | | | |",
        "",
        "The command runs as `make` leaves it: the project's modules byte-compiled "
        "(`make bytecode`, as pip does for an installed wheel). The no-cached-bytecode row runs "
        "a copy of the sources with none, and writes none.",
        "",
        "CPU time (user + system; what the figures would be on an idle machine):",
        "",
        "| figure | median | target | met |",
        "|---|---|---|---|",
        f"| floor [s CPU] | {cpu['floor']:.3f} | | |",
        f"| `cablecal identify`, 100 rows [s CPU] | {cpu['identify_100']:.3f} | | |",
        f"| ratio identify / floor | {cfig['ratio_100']:.2f} | <= {TARGETS['ratio_100']} | "
        f"{'yes' if r['met_cpu']['ratio_100'] else 'no'} |",
        f"| identify, 100 rows, in process [s CPU] | {cfig['elapsed_100_s']:.3f} | "
        f"<= {TARGETS['elapsed_100_s']} | {'yes' if r['met_cpu']['elapsed_100_s'] else 'no'} |",
        f"| identify, 2017 rows, in process [s CPU] | {cfig['elapsed_2017_s']:.3f} | "
        f"<= {TARGETS['elapsed_2017_s']} | {'yes' if r['met_cpu']['elapsed_2017_s'] else 'no'} |",
        "",
        "Top-level imports of the 100-row command (cumulative, at least "
        f"{IMPORT_LIST_US // 1000} ms; one `-X importtime` run):",
        "",
        "| module | ms |",
        "|---|---|",
        *(f"| `{name}` | {ms:.0f} |" for name, ms in r["top_imports_ms"]),
        "",
    ]
    return "\n".join(lines)


if __name__ == "__main__":
    main()
