"""``cablecal filter``: speed on 10,000 targets and accuracy on an EMULATED truth.

Setup (``tests/filter_cells.py``): hsr-jr680 with the cable hook 45, -30, 95 mm off the
flange, the true robot of Table XII D1 without the unobservable terms (d1, theta1, the
joint-6 row), identified (the default method, every row for training) from 200 cable
lengths shown to 0.01 mm, noise-free (and once with ``NOISE_MM`` of noise). Programs planned
offline on the nominal model (joints away from singularities, a tool 185–240 mm out and
tilted, a work object turned 30° with an oframe).

Speed: :func:`calib.filter.run.filter_files` on one RAPID module of 10,000 robtargets
(parse, nominal IK on the written configuration, calibrated IK seeded from it, σ at the
tool, writing the numbers back): median of ``REPEATS`` runs. Baseline in the same run: the
same work target by target (one module of one target per call) on ``N_LOOP`` targets,
scaled to 10,000. The machine is shared (see the load average): a loop of 10⁶ additions
is timed beside it as a probe of how busy it was.

Accuracy: the true robot executing the filtered program through the nominal controller on
the written branch (RAPID: the configuration; UR: nearest the waypoint's q or the previous
move's joints) against the intended poses; the unfiltered program; and the floor (the
calibrated model's own tool-pose error at the corrected joints, see
tests/test_filter_accuracy.py).

Writes ``bench/filter.json`` and ``bench/filter.md``.
"""

from __future__ import annotations

import json
import statistics
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from bench.run import environment
from calib.filter.branches import flange_frames, nominal_solutions
from calib.filter.correct import IK_OPTIONS, calibration_from_result
from calib.filter.rapid import DIALECT as RAPID
from calib.filter.rotations import invert, rotation_angle_deg
from calib.filter.run import filter_files
from calib.filter.select import choose
from calib.filter.sites import FrameTables, Source
from calib.filter.urscript import DIALECT as URSCRIPT
from calib.ik import solve_ik
from calib.kinematics import FloatArray

sys.path.insert(0, str(Path(__file__).parents[1] / "tests"))
from filter_cells import (
    Cell,
    make_cell,
    planned_targets,
    rapid_module,
    regular_poses,
    smooth_path,
    tool_frame,
    urscript,
    work_frame,
)

OUT = Path(__file__).parent
N_TARGETS = 10_000
N_LOOP = 200
REPEATS = 3
#: Noise of the lengths of the second identification [mm] (1σ).
NOISE_MM = 0.05


def _probe_s() -> float:
    t = time.perf_counter()
    s = 0
    for i in range(1_000_000):
        s += i
    return time.perf_counter() - t


def speed(cell: Cell) -> dict[str, Any]:
    nominal = cell.nominal
    cal = calibration_from_result(cell.result, nominal)
    q = regular_poses(nominal, N_TARGETS, seed=1)
    tool, work = tool_frame(220.0), work_frame()
    text = rapid_module(nominal, q, tool, work).encode()
    times, probes = [], []
    for _ in range(REPEATS):
        probes.append(_probe_s())
        t = time.perf_counter()
        run = filter_files(cal, [("olp.mod", text)])
        times.append(time.perf_counter() - t)
    corrected = sum(c.status == "corrected" for c in run.corrections)
    singles = [rapid_module(nominal, q[i : i + 1], tool, work).encode() for i in range(N_LOOP)]
    t = time.perf_counter()
    for body in singles:
        filter_files(cal, [("one.mod", body)])
    loop_s = time.perf_counter() - t
    return {"targets": N_TARGETS, "corrected": corrected, "bytes": len(text),
            "vectorised_s": statistics.median(times), "runs_s": times,
            "loop_targets": N_LOOP, "loop_s": loop_s,
            "loop_scaled_s": loop_s * N_TARGETS / N_LOOP,
            "probe_1e6_additions_s": statistics.median(probes)}  # fmt: skip


def _rms(v: FloatArray) -> float:
    return float(np.sqrt(np.mean(np.asarray(v) ** 2)))


def _figures(cell: Cell, q_plan: FloatArray, q_exec: FloatArray, q_star: FloatArray,
             tool: FloatArray, work: FloatArray) -> dict[str, float]:  # fmt: skip
    intended = planned_targets(cell.nominal, q_plan, tool, work)

    def err(q: FloatArray) -> tuple[FloatArray, FloatArray]:
        reached = invert(work) @ cell.true_flange(q) @ tool
        return (np.linalg.norm(reached[:, :3, 3] - intended[:, :3, 3], axis=1),
                rotation_angle_deg(reached[:, :3, :3], intended[:, :3, :3]))  # fmt: skip

    cal = calibration_from_result(cell.result, cell.nominal).calibrated
    true, model = cell.true_flange(q_star) @ tool, flange_frames(cal, q_star) @ tool
    floor_mm = np.linalg.norm(true[:, :3, 3] - model[:, :3, 3], axis=1)
    floor_deg = rotation_angle_deg(true[:, :3, :3], model[:, :3, :3])
    unf_mm, unf_deg = err(q_plan)
    fil_mm, fil_deg = err(q_exec)
    return {"n": int(q_plan.shape[0]),
            "unfiltered_rms_mm": _rms(unf_mm), "filtered_rms_mm": _rms(fil_mm),
            "floor_rms_mm": _rms(floor_mm), "max_filtered_minus_floor_mm": float(
                np.max(fil_mm - floor_mm)),
            "unfiltered_rms_deg": _rms(unf_deg), "filtered_rms_deg": _rms(fil_deg),
            "floor_rms_deg": _rms(floor_deg)}  # fmt: skip


def accuracy(cell: Cell, noisy: Cell) -> dict[str, dict[str, float]]:
    nominal = cell.nominal
    out: dict[str, dict[str, float]] = {}
    for tool_mm, c in ((185.0, cell), (240.0, cell), (220.0, noisy)):
        cal = calibration_from_result(c.result, nominal)
        q_plan = regular_poses(nominal, 100, seed=int(tool_mm))
        tool, work = tool_frame(tool_mm), work_frame()
        run = filter_files(cal, [("a.mod", rapid_module(nominal, q_plan, tool, work).encode())])
        done = [t for t in RAPID.parse([Source.from_bytes("a.mod", run.outputs["a.mod"])],
                                       FrameTables()) if t.kind == "cartesian"]  # fmt: skip
        fl = np.array([work @ t.pose @ invert(tool) for t in done])  # type: ignore[operator]
        sol = nominal_solutions(nominal, fl)
        idx, _ = choose(sol, [t.configuration for t in done])
        q_exec = sol.joints_deg[np.arange(len(done)), idx]
        q_star = np.array([c.joints_deg for c in run.corrections])
        name = f"RAPID, tool {tool_mm:.0f} mm" + (f", lengths σ {NOISE_MM} mm" if c is noisy
                                                  else "")  # fmt: skip
        out[name] = _figures(c, q_plan, q_exec, q_star, tool, work)
    cal = calibration_from_result(cell.result, nominal)
    q_plan = regular_poses(nominal, 100, seed=7)
    tool = tool_frame(200.0)
    run = filter_files(cal, [("p.script", urscript(nominal, q_plan, tool).encode())])
    filtered = Source.from_bytes("p.script", run.outputs["p.script"])
    got = {t.name: t for t in URSCRIPT.parse([filtered], FrameTables())}
    poses = np.array([got[f"Waypoint_{i + 1}_p"].pose for i in range(100)])
    qs = np.array([got[f"Waypoint_{i + 1}_q"].joints_deg for i in range(100)])
    fl = poses @ invert(tool)
    q_exec = solve_ik(nominal, qs, fl[:, :3, 3], fl[:, :3, :3], np.zeros(3), IK_OPTIONS).joints_deg
    by = {t.name: c for t, c in zip(run.targets, run.corrections, strict=True)}
    q_star = np.array([by[f"Waypoint_{i + 1}_p"].joints_deg for i in range(100)])
    out["URScript (PolyScope), tool 200 mm"] = _figures(cell, q_plan, q_exec, q_star, tool,
                                                        np.eye(4))  # fmt: skip
    q_plan = smooth_path(nominal, 60, seed=4)
    tool = tool_frame(230.0, tilt_deg=10.0)
    run = filter_files(cal, [("d.script", urscript(nominal, q_plan, tool, polyscope=False)
                              .encode())])  # fmt: skip
    targets = URSCRIPT.parse([Source.from_bytes("d.script", run.outputs["d.script"])],
                             FrameTables())  # fmt: skip
    q_prev = np.asarray(targets[0].joints_deg)
    execs = []
    for t in targets[1:]:
        f = (t.pose @ invert(tool))[None]  # type: ignore[operator]
        q_prev = solve_ik(nominal, q_prev[None], f[:, :3, 3], f[:, :3, :3], np.zeros(3),
                          IK_OPTIONS).joints_deg[0]  # fmt: skip
        execs.append(q_prev)
    q_star = np.array([c.joints_deg for t, c in zip(run.targets, run.corrections, strict=True)
                       if t.kind == "cartesian"])  # fmt: skip
    out["URScript (movel path), tool 230 mm"] = _figures(cell, q_plan, np.array(execs), q_star,
                                                         tool, np.eye(4))  # fmt: skip
    return out


def markdown(env: dict[str, Any], sp: dict[str, Any], acc: dict[str, dict[str, float]]) -> str:
    lines = [
        "# cablecal filter: speed and accuracy",
        "",
        f"Machine: {env['machine']}, {env['cpus']} CPUs (shared), Python {env['python']}, "
        f"numpy {env['numpy']}; load average at the start {env['load_average_1_5_15']}. "
        "Setup and method: `bench/filter_bench.py`.",
        "",
        "## Speed",
        "",
        f"One RAPID module of {sp['targets']:,} robtargets ({sp['bytes'] / 1e6:.1f} MB; "
        f"{sp['corrected']:,} corrected), the whole `filter_files` (parse, nominal IK on the "
        "written configuration, calibrated IK seeded from it, σ at the tool, numbers written "
        "back).",
        "",
        "| way | time [s] |",
        "|---|---:|",
        f"| vectorised, median of {len(sp['runs_s'])} | {sp['vectorised_s']:.2f} |",
        f"| per-target loop, {sp['loop_targets']} targets scaled to {sp['targets']:,} | "
        f"{sp['loop_scaled_s']:.1f} |",
        "",
        f"Runs: {', '.join(f'{t:.2f}' for t in sp['runs_s'])} s. Busy-machine probe (the "
        f"machine is shared): a Python loop of 10⁶ additions took "
        f"{sp['probe_1e6_additions_s']:.3f} s (median, beside the runs); the times above "
        "scale with it.",
        "",
        "## Accuracy on an EMULATED truth",
        "",
        "RMS over the targets of the true robot's error against the intended pose; the floor "
        "is the calibrated model's own error at the corrected joints.",
        "",
        "| program | n | unfiltered [mm] | filtered [mm] | floor [mm] | max filtered − floor "
        "[mm] | unfiltered [°] | filtered [°] | floor [°] |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for name, f in acc.items():
        lines.append(f"| {name} | {f['n']} | {f['unfiltered_rms_mm']:.3f} | "
                     f"{f['filtered_rms_mm']:.4f} | {f['floor_rms_mm']:.4f} | "
                     f"{f['max_filtered_minus_floor_mm']:.4f} | {f['unfiltered_rms_deg']:.4f} | "
                     f"{f['filtered_rms_deg']:.5f} | {f['floor_rms_deg']:.5f} |")  # fmt: skip
    lines += [
        "",
        f"The identifications are noise-free (0.01 mm display only) but for the row with "
        f"lengths of σ = {NOISE_MM} mm: there the floor is larger, and the filtered error "
        "follows it.",
        "",
    ]
    return "\n".join(lines)


def main() -> None:
    env = environment()
    cell = make_cell()
    sp = speed(cell)
    acc = accuracy(cell, make_cell(noise_mm=NOISE_MM))
    (OUT / "filter.json").write_text(json.dumps({"environment": env, "speed": sp,
                                                 "accuracy": acc}, indent=2) + "\n")  # fmt: skip
    (OUT / "filter.md").write_text(markdown(env, sp, acc))
    print((OUT / "filter.md").read_text())


if __name__ == "__main__":
    main()
