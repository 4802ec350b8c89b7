"""``cablecal filter``'s speed and peak memory per dialect, this checkout against another.

Each measurement is a fresh process (``python bench/filter_speed.py --child DIR DIALECT``
with ``PYTHONPATH`` the checkout measured): it loads the result, the model and the program
files, runs :func:`calib.filter.run.filter_files` once, and reports the run's wall and CPU
time and the process's peak resident set (``ru_maxrss``: the imports, the data and the run,
what a ``cablecal filter`` process costs) and the resident set just before the run. The
checkouts take turns, ``rounds`` times each, so the shared machine's load falls on both
alike. The other checkout is ``git archive REV`` unpacked in a temporary directory.

Programs (written once by this checkout, read by both): the four dialects of
``bench/filter_bench.py`` and ``RAPID, shapes``: one module of 10,000 targets in the shapes
real modules hold (:mod:`bench.filter_shapes`).
"""

from __future__ import annotations

import hashlib
import json
import os
import resource
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).parents[1]


def peak_rss_mb() -> float:
    """This process's peak resident set [MB]: ``VmHWM`` (Linux; it starts afresh at exec,
    where ``ru_maxrss`` keeps the forking parent's peak), else ``ru_maxrss``."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def _child(directory: Path, dialect: str, gc_off: bool = False) -> None:
    """Run once and print the figures as JSON (in the measured checkout's code); with
    ``gc_off`` the cyclic garbage collector is off during the run (what ``gc.disable()``
    in the library bought, measured in the same run)."""
    import gc

    from calib.filter.correct import calibration_from_result
    from calib.filter.run import filter_files
    from calib.programs.sites import parse_frames_toml
    from daemon.datafiles import load_robot

    d = directory / dialect
    spec = json.loads((d / "spec.json").read_text())
    result = json.loads((directory / "result.json").read_text())
    nominal = load_robot(str(directory / "robot.toml"))
    cal = calibration_from_result(result, nominal)
    frames = None
    if (d / "frames.toml").exists():
        frames = parse_frames_toml((d / "frames.toml").read_text())
    files = [(name, (d / "files" / name).read_bytes()) for name in spec["files"]]
    rss_before = peak_rss_mb()
    if gc_off:
        gc.disable()
    t, c = time.perf_counter(), time.process_time()
    run = filter_files(cal, files, frames=frames)
    wall, cpu = time.perf_counter() - t, time.process_time() - c
    gc.enable()
    digest = hashlib.sha256()
    for name in sorted(run.outputs):
        digest.update(f"{len(name)}:{name}:{len(run.outputs[name])}:".encode())
        digest.update(run.outputs[name])
    print(
        json.dumps(
            {
                "wall_s": wall,
                "cpu_s": cpu,
                "peak_rss_mb": peak_rss_mb(),
                "rss_before_run_mb": rss_before,
                "targets": len(run.targets),
                "corrected": sum(c.status == "corrected" for c in run.corrections),
                "errors": [str(e) for e in run.errors],
                "outputs_sha256": digest.hexdigest(),
            }
        )
    )


def write_programs(
    directory: Path,
    result: dict[str, Any],
    robot_toml: str,
    programs: dict[str, tuple[list[tuple[str, bytes]], str | None]],
) -> None:
    """Lay out the result, the model and each dialect's files (and frames TOML) for children."""
    directory.mkdir(parents=True, exist_ok=True)
    (directory / "result.json").write_text(json.dumps(result))
    (directory / "robot.toml").write_text(robot_toml)
    for dialect, (files, frames) in programs.items():
        d = directory / dialect
        (d / "files").mkdir(parents=True)
        for name, data in files:
            (d / "files" / name).write_bytes(data)
        if frames is not None:
            (d / "frames.toml").write_text(frames)
        spec = {"files": [n for n, _ in files], "bytes": sum(len(b) for _, b in files)}
        (d / "spec.json").write_text(json.dumps(spec))


def checkout(rev: str, into: Path) -> Path:
    """``git archive rev`` of this repository unpacked under ``into``; its path."""
    out = into / f"checkout-{rev.replace('/', '_')}"
    out.mkdir()
    tar = subprocess.run(
        ["git", "-C", str(ROOT), "archive", "--format=tar", rev],
        check=True,
        capture_output=True,
    ).stdout
    tmp = into / "checkout.tar"
    tmp.write_bytes(tar)
    with tarfile.open(tmp) as tf:
        tf.extractall(out, filter="data")
    tmp.unlink()
    return out


def _one(code: Path, directory: Path, dialect: str, gc_off: bool) -> dict[str, Any]:
    env = {**os.environ, "PYTHONPATH": str(code)}
    argv = ["--child", str(directory), dialect, *(["gc-off"] if gc_off else [])]
    proc = subprocess.run(
        [sys.executable, str(Path(__file__).resolve()), *argv],
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    if proc.returncode != 0:
        raise RuntimeError(f"{code} {dialect}: {proc.stderr[-2000:]}")
    out: dict[str, Any] = json.loads(proc.stdout.strip().splitlines()[-1])
    return out


def measure(
    directory: Path,
    codes: dict[str, tuple[Path, bool]],
    dialects: list[str],
    rounds: int | dict[str, int],
) -> dict[str, dict[str, dict[str, Any]]]:
    """Per label (a checkout, and whether the GC is off in the run) and dialect: the runs
    and their medians (time) and maxima (RSS); ``rounds`` per dialect or for all. Each
    dialect's output bytes are compared across the labels (``same_output``: the SHA-256 of
    every output file, names and lengths included, equal to the first label's, run by run).
    """
    runs: dict[str, dict[str, list[dict[str, Any]]]] = {k: {d: [] for d in dialects} for k in codes}
    loads: dict[str, list[float]] = {}
    for dialect in dialects:
        loads[dialect] = [round(v, 2) for v in os.getloadavg()]
        for _ in range(rounds if isinstance(rounds, int) else rounds[dialect]):
            for label, (code, gc_off) in codes.items():
                runs[label][dialect].append(_one(code, directory, dialect, gc_off))
    out: dict[str, dict[str, dict[str, Any]]] = {}
    first = next(iter(codes))
    for label in codes:
        out[label] = {}
        for dialect in dialects:
            rs = runs[label][dialect]
            spec = json.loads((directory / dialect / "spec.json").read_text())
            out[label][dialect] = {
                "targets": rs[0]["targets"],
                "corrected": rs[0]["corrected"],
                "errors": rs[0]["errors"],
                "bytes": spec["bytes"],
                "wall_s": statistics.median(r["wall_s"] for r in rs),
                "runs_s": [r["wall_s"] for r in rs],
                "cpu_s": statistics.median(r["cpu_s"] for r in rs),
                "peak_rss_mb": max(r["peak_rss_mb"] for r in rs),
                "rss_before_run_mb": max(r["rss_before_run_mb"] for r in rs),
                "load_average_1_5_15": loads[dialect],
                "outputs_sha256": rs[0]["outputs_sha256"],
                "same_output": all(
                    r["outputs_sha256"] == runs[first][dialect][0]["outputs_sha256"] for r in rs
                ),
            }
    return out


def markdown(sp: dict[str, dict[str, dict[str, Any]]], labels: dict[str, str]) -> list[str]:
    """The speed section's table: one row per dialect and checkout."""
    lines = [
        "| dialect | checkout | targets | corrected | MB | wall [s] (median) | runs [s] | "
        "CPU [s] (median) | peak RSS [MB] | RSS before the run [MB] | output bytes as "
        "`this` | load average 1/5/15 |",
        "|---|---|---:|---:|---:|---:|---|---:|---:|---:|---|---|",
    ]
    dialects = list(next(iter(sp.values())))
    for dialect in dialects:
        for label, by in sp.items():
            if dialect not in by:
                continue
            r = by[dialect]
            runs = ", ".join(f"{t:.2f}" for t in r["runs_s"])
            lines.append(
                f"| {dialect} | {labels[label]} | {r['targets']:,} | {r['corrected']:,} | "
                f"{r['bytes'] / 1e6:.1f} | {r['wall_s']:.2f} | {runs} | {r['cpu_s']:.2f} | "
                f"{r['peak_rss_mb']:.0f} | {r['rss_before_run_mb']:.0f} | "
                f"{'identical' if r['same_output'] else 'DIFFERENT'} | "
                f"{r['load_average_1_5_15']} |"
            )
    return lines


def temporary() -> tempfile.TemporaryDirectory[str]:
    return tempfile.TemporaryDirectory(prefix="cablecal-filter-speed-")


if __name__ == "__main__" and len(sys.argv) in (4, 5) and sys.argv[1] == "--child":
    _child(Path(sys.argv[2]), sys.argv[3], sys.argv[4:] == ["gc-off"])
