"""``cablecal filter``: speed on 10,000 targets and accuracy on an EMULATED truth.

Setup (``tests/filter_cells.py``): hsr-jr680 with the cable hook 45, -30, 95 mm off the
flange, the true robot of Table XII D1 without the unobservable terms (d1, theta1, the
joint-6 row), identified (the default method, every row for training) from 200 cable
lengths shown to 0.01 mm, noise-free (and once with ``NOISE_MM`` of noise). Programs planned
offline on the nominal model (joints away from singularities, a tool 185–240 mm out and
tilted, a work object turned 30° with an oframe).

Speed, per dialect: :func:`calib.filter.run.filter_files` on one program of 10,000 targets
(parse, nominal IK on the written configuration, calibrated IK seeded from it, σ at the tool,
writing the numbers back): median of ``REPEATS`` runs. RAPID: one module of 10,000
robtargets; URScript: a PolyScope program of 5,000 waypoints (``Waypoint_n_p`` and the
``Waypoint_n_q`` that follows it: 10,000 targets); KRL: ``.src``/``.dat`` with
``$config.dat`` (a third inline ``LIN {…}``, the rest ``E6POS`` with their ``FDAT``, and
``XHOME``); Fanuc LS: one ``.ls`` of 10,000 ``P[n]`` (every other with a ``GP2``) and
``HOME`` in joint form, with ``--frames``. Baseline in the same run: the same work program by
program of one target each on ``N_LOOP`` targets, scaled to 10,000. The machine is shared
(see the load average, taken before each dialect): a loop of 10⁶ additions is timed beside
the runs as a probe of how busy it was. ``--speed-only`` prints the speed as JSON and writes
nothing (to time another checkout: ``PYTHONPATH=<checkout> python bench/filter_bench.py
--speed-only``).

Accuracy: the true robot executing the filtered program through the nominal controller on
the written branch (RAPID: the configuration; KRL: ``S`` and ``T``; Fanuc: ``CONFIG`` and
the turns; UR: nearest the waypoint's q or the previous move's joints) against the intended
poses; the unfiltered program; and the floor (the calibrated model's own tool-pose error at
the corrected joints, see tests/test_filter_accuracy.py and tests/filter_olp.py). KRL and LS
rows include their joint-form home position (at the flange).

Writes ``bench/filter.json`` and ``bench/filter.md``.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from bench.filter_shapes import rapid_shapes
from bench.filter_speed import ROOT, checkout, measure, temporary, write_programs
from bench.filter_speed import markdown as speed_table
from bench.run import environment
from calib.export import model_to_toml
from calib.filter.branches import flange_frames, nominal_solutions
from calib.filter.correct import IK_OPTIONS, calibration_from_result
from calib.filter.run import filter_files
from calib.filter.select import choose
from calib.ik import solve_ik
from calib.kinematics import FloatArray
from calib.programs.fanuc.filter import DIALECT as LS
from calib.programs.krl.filter import DIALECT as KRL
from calib.programs.rapid.filter import DIALECT as RAPID
from calib.programs.rotations import invert, rotation_angle_deg
from calib.programs.sites import FrameTables, Source, parse_frames_toml
from calib.programs.urscript.filter import DIALECT as URSCRIPT

sys.path.insert(0, str(Path(__file__).parents[1] / "tests"))
from filter_cells import (
    Cell,
    make_cell,
    planned_targets,
    rapid_confdata,
    rapid_module,
    regular_poses,
    smooth_path,
    tool_frame,
    urscript,
    work_frame,
)
from filter_olp import accuracy as olp_accuracy
from filter_olp import frames_toml, krl_program, ls_program, rms

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


def _program(
    dialect: str, cell: Cell, q: FloatArray
) -> tuple[list[tuple[str, bytes]], FrameTables | None]:
    """The files of a program of the targets at joints ``q`` (n, 6) [deg]."""
    nominal, tool, work = cell.nominal, tool_frame(220.0), work_frame()
    if dialect == "RAPID":
        return [("olp.mod", rapid_module(nominal, q, tool, work).encode())], None
    if dialect == "URScript":
        return [("olp.script", urscript(nominal, q, tool).encode())], None
    if dialect == "KRL":
        files = krl_program(nominal, q, tool, work)
        return [(k, v.encode("latin-1")) for k, v in files.items()], None
    frames = parse_frames_toml(frames_toml(tool, work))
    return [("OLP.LS", ls_program(nominal, q, tool, work).encode("ascii"))], frames


#: Planned joints per target of each dialect's program (a PolyScope waypoint is two targets).
_PER_TARGET = {"RAPID": 1.0, "URScript": 0.5, "KRL": 1.0, "Fanuc LS": 1.0}
SHAPES = "RAPID, shapes"
#: The upload of issue 31 item 4: a RAPID module of targets in real shapes, just under
#: 16 MiB (the service's upload limit), run once per checkout.
UPLOAD = "RAPID, 16 MiB upload"
UPLOAD_TARGETS = 85_500


def programs(cell: Cell) -> dict[str, tuple[list[tuple[str, bytes]], str | None]]:
    """Each dialect's program of 10,000 targets (files, frames TOML or None)."""
    out: dict[str, tuple[list[tuple[str, bytes]], str | None]] = {}
    for dialect, per in _PER_TARGET.items():
        q = regular_poses(cell.nominal, int(N_TARGETS * per), seed=1)
        files, _ = _program(dialect, cell, q)
        frames = frames_toml(tool_frame(220.0), work_frame()) if dialect == "Fanuc LS" else None
        out[dialect] = (files, frames)
    q = regular_poses(cell.nominal, N_TARGETS, seed=2)
    tools = [tool_frame(185.0), tool_frame(220.0, 10.0), tool_frame(240.0, 30.0)]
    text = rapid_shapes(cell.nominal, q, tools, work_frame(), rapid_confdata(cell.nominal, q))
    out[SHAPES] = ([("SHAPES.mod", text.encode())], None)
    q = regular_poses(cell.nominal, UPLOAD_TARGETS, seed=3)
    text = rapid_shapes(cell.nominal, q, tools, work_frame(), rapid_confdata(cell.nominal, q))
    if len(text.encode()) > 16 * 2**20:
        raise AssertionError(f"the upload is {len(text.encode())} bytes, over 16 MiB")
    out[UPLOAD] = ([("UPLOAD.mod", text.encode())], None)
    return out


def speeds(
    cell: Cell, against: str | None, rounds: int = REPEATS
) -> tuple[dict[str, dict[str, dict[str, Any]]], dict[str, str]]:
    """Per checkout ("this", and "before" = ``against``) and dialect, the figures of
    :func:`bench.filter_speed.measure`; and the checkouts' labels."""
    labels = {"this": "this", "this-gc-off": "this, GC off in the run"}
    with temporary() as tmp:
        d = Path(tmp)
        write_programs(d / "data", cell.result, model_to_toml(cell.nominal), programs(cell))
        codes = {"this": (ROOT, False), "this-gc-off": (ROOT, True)}
        if against:
            codes["before"] = (checkout(against, d), False)
            labels["before"] = f"before ({against})"
        sp = measure(d / "data", codes, [*_PER_TARGET, SHAPES], rounds)
        up = measure(
            d / "data", {k: v for k, v in codes.items() if k != "this-gc-off"}, [UPLOAD], 1
        )
    for label, by in up.items():
        sp[label][UPLOAD] = by[UPLOAD]
    return sp, labels


def _rms(v: FloatArray) -> float:
    return float(np.sqrt(np.mean(np.asarray(v) ** 2)))


def _figures(
    cell: Cell,
    q_plan: FloatArray,
    q_exec: FloatArray,
    q_star: FloatArray,
    tool: FloatArray,
    work: FloatArray,
) -> dict[str, float]:
    intended = planned_targets(cell.nominal, q_plan, tool, work)

    def err(q: FloatArray) -> tuple[FloatArray, FloatArray]:
        reached = invert(work) @ cell.true_flange(q) @ tool
        return (
            np.linalg.norm(reached[:, :3, 3] - intended[:, :3, 3], axis=1),
            rotation_angle_deg(reached[:, :3, :3], intended[:, :3, :3]),
        )

    cal = calibration_from_result(cell.result, cell.nominal).calibrated
    true, model = cell.true_flange(q_star) @ tool, flange_frames(cal, q_star) @ tool
    floor_mm = np.linalg.norm(true[:, :3, 3] - model[:, :3, 3], axis=1)
    floor_deg = rotation_angle_deg(true[:, :3, :3], model[:, :3, :3])
    unf_mm, unf_deg = err(q_plan)
    fil_mm, fil_deg = err(q_exec)
    return {
        "n": int(q_plan.shape[0]),
        "unfiltered_rms_mm": _rms(unf_mm),
        "filtered_rms_mm": _rms(fil_mm),
        "floor_rms_mm": _rms(floor_mm),
        "max_filtered_minus_floor_mm": float(np.max(fil_mm - floor_mm)),
        "unfiltered_rms_deg": _rms(unf_deg),
        "filtered_rms_deg": _rms(fil_deg),
        "floor_rms_deg": _rms(floor_deg),
    }


def accuracy(cell: Cell, noisy: Cell) -> dict[str, dict[str, float]]:
    nominal = cell.nominal
    out: dict[str, dict[str, float]] = {}
    for tool_mm, c in ((185.0, cell), (240.0, cell), (220.0, noisy)):
        cal = calibration_from_result(c.result, nominal)
        q_plan = regular_poses(nominal, 100, seed=int(tool_mm))
        tool, work = tool_frame(tool_mm), work_frame()
        run = filter_files(cal, [("a.mod", rapid_module(nominal, q_plan, tool, work).encode())])
        done = [
            t
            for t in RAPID.parse([Source.from_bytes("a.mod", run.outputs["a.mod"])], FrameTables())
            if t.kind == "cartesian"
        ]
        fl = np.array([work @ t.pose @ invert(tool) for t in done])  # type: ignore[operator]
        sol = nominal_solutions(nominal, fl)
        idx, _ = choose(sol, [t.configuration for t in done])
        q_exec = sol.joints_deg[np.arange(len(done)), idx]
        q_star = np.array([c.joints_deg for c in run.corrections])
        name = f"RAPID, tool {tool_mm:.0f} mm" + (
            f", lengths σ {NOISE_MM} mm" if c is noisy else ""
        )
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
    out["URScript (PolyScope), tool 200 mm"] = _figures(
        cell, q_plan, q_exec, q_star, tool, np.eye(4)
    )
    q_plan = smooth_path(nominal, 60, seed=4)
    tool = tool_frame(230.0, tilt_deg=10.0)
    run = filter_files(
        cal, [("d.script", urscript(nominal, q_plan, tool, polyscope=False).encode())]
    )
    targets = URSCRIPT.parse(
        [Source.from_bytes("d.script", run.outputs["d.script"])], FrameTables()
    )
    q_prev = np.asarray(targets[0].joints_deg)
    execs = []
    for t in targets[1:]:
        f = (t.pose @ invert(tool))[None]  # type: ignore[operator]
        q_prev = solve_ik(
            nominal, q_prev[None], f[:, :3, 3], f[:, :3, :3], np.zeros(3), IK_OPTIONS
        ).joints_deg[0]
        execs.append(q_prev)
    q_star = np.array(
        [
            c.joints_deg
            for t, c in zip(run.targets, run.corrections, strict=True)
            if t.kind == "cartesian"
        ]
    )
    out["URScript (movel path), tool 230 mm"] = _figures(
        cell, q_plan, np.array(execs), q_star, tool, np.eye(4)
    )
    out.update(_krl_ls_rows(cell, noisy))
    return out


def _row(acc: dict[str, FloatArray]) -> dict[str, float]:
    return {
        "n": int(acc["filtered_mm"].size),
        "unfiltered_rms_mm": rms(acc["unfiltered_mm"]),
        "filtered_rms_mm": rms(acc["filtered_mm"]),
        "floor_rms_mm": rms(acc["floor_mm"]),
        "max_filtered_minus_floor_mm": float(np.max(acc["filtered_mm"] - acc["floor_mm"])),
        "unfiltered_rms_deg": rms(acc["unfiltered_deg"]),
        "filtered_rms_deg": rms(acc["filtered_deg"]),
        "floor_rms_deg": rms(acc["floor_deg"]),
    }


def _krl_ls_rows(cell: Cell, noisy: Cell) -> dict[str, dict[str, float]]:
    """KRL (``$config.dat`` TOOL_DATA/BASE_DATA) and Fanuc LS (``--frames``) programs."""
    nominal, work = cell.nominal, work_frame()
    out: dict[str, dict[str, float]] = {}
    ls_rows: dict[str, dict[str, float]] = {}
    for tool_mm, c in ((185.0, cell), (240.0, cell), (220.0, noisy)):
        cal = calibration_from_result(c.result, nominal)
        noise = f", lengths σ {NOISE_MM} mm" if c is noisy else ""
        q_plan = regular_poses(nominal, 100, seed=int(tool_mm) + 1)
        tool = tool_frame(tool_mm)
        files = {
            k: v.encode("latin-1") for k, v in krl_program(nominal, q_plan, tool, work).items()
        }
        run = filter_files(cal, list(files.items()))
        out[f"KRL, tool {tool_mm:.0f} mm{noise}"] = _row(
            olp_accuracy(c, KRL, files, run, FrameTables())
        )
        q_plan = regular_poses(nominal, 100, seed=int(tool_mm) + 2)
        tool = tool_frame(tool_mm, tilt_deg=30.0)
        frames = parse_frames_toml(frames_toml(tool, work))
        files = {"OLP.LS": ls_program(nominal, q_plan, tool, work).encode("ascii")}
        run = filter_files(cal, list(files.items()), frames=frames)
        ls_rows[f"Fanuc LS, tool {tool_mm:.0f} mm{noise}"] = _row(
            olp_accuracy(c, LS, files, run, frames)
        )
    return {**out, **ls_rows}


def summary_table(sp: dict[str, dict[str, dict[str, Any]]], labels: dict[str, str]) -> list[str]:
    """Per program: CPU, wall and peak RSS of this checkout and the one before, side by side
    (empty without a checkout before)."""
    if "before" not in sp:
        return []
    lines = [
        f"| program | CPU [s] this / {labels['before']} | wall [s] this / before | peak RSS "
        "[MB] this / before | output bytes |",
        "|---|---:|---:|---:|---|",
    ]
    for dialect, r in sp["this"].items():
        b = sp["before"].get(dialect)
        if b is None:
            continue
        lines.append(
            f"| {dialect} | {r['cpu_s']:.2f} / {b['cpu_s']:.2f} | {r['wall_s']:.2f} / "
            f"{b['wall_s']:.2f} | {r['peak_rss_mb']:.0f} / {b['peak_rss_mb']:.0f} | "
            f"{'identical' if b['same_output'] else 'DIFFERENT'} |"
        )
    return lines


def markdown(
    env: dict[str, Any],
    sp: dict[str, dict[str, dict[str, Any]]],
    labels: dict[str, str],
    acc: dict[str, dict[str, float]],
) -> str:
    lines = [
        "# cablecal filter: speed and accuracy",
        "",
        f"Machine: {env['machine']}, {env['cpus']} CPUs, Python {env['python']}, "
        f"numpy {env['numpy']}; load average at the start {env['load_average_1_5_15']}. "
        "The machine was SHARED: other sessions ran their tests and benches on the same two "
        "cores during the run (the load average before each program is in the table), so "
        "wall times carry their load and vary from run to run; the fair figure is the CPU "
        "time, the process's own (`time.process_time`). Setup and method: "
        "`bench/filter_bench.py` and `bench/filter_speed.py`.",
        "",
        "## Speed and memory",
        "",
        "The whole `filter_files` on one program of each dialect (parse, nominal IK on the "
        "written configuration, calibrated IK seeded from it, σ at the tool, numbers written "
        "back), each run in a fresh process; the checkouts take turns, "
        f"{len(next(iter(sp.values()))['RAPID']['runs_s'])} runs each (the 16 MiB upload: "
        "one each). Peak RSS is the process's whole peak (imports, data and run: what a "
        "`cablecal filter` process costs); RSS before the run is what the imports and the "
        "data took before it. `output bytes as this`: the SHA-256 of every output file of "
        "every run equals this checkout's first run (the speed work changes no byte). The "
        "issues' targets: 10,000 targets in ≤ 2 s and ≤ 200 MB per dialect (issue 34); a "
        "16 MiB upload's working set ≤ 200 MB (issue 31).",
        "",
        *summary_table(sp, labels),
        "",
        *speed_table(sp, labels),
        "",
        "`RAPID, shapes` is one module of 10,000 targets in the shapes real modules hold "
        "(`bench/filter_shapes.py`: one-line and multi-line CONST/PERS/VAR robtargets, arrays "
        "used by index, inline targets, MoveC, MoveAbsJ joint targets, three tools, two work "
        "objects, 0 to 8 decimals, routines of 400 moves). "
        f"`{UPLOAD}` is such a module of {UPLOAD_TARGETS:,} targets, just under 16 MiB (the "
        "service's upload limit). URScript's 10,000 targets are 5,000 PolyScope waypoints "
        "(`Waypoint_n_p` and the `Waypoint_n_q` that follows it).",
        "",
        "`this, GC off in the run` is this checkout with the cyclic garbage collector off "
        "around the run, as an older `filter_files` did itself with `gc.disable()`: the row "
        "measures what that would buy. The library leaves the collector alone (the service "
        "filters requests concurrently, and the switch is the process's).",
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
        lines.append(
            f"| {name} | {f['n']} | {f['unfiltered_rms_mm']:.3f} | "
            f"{f['filtered_rms_mm']:.4f} | {f['floor_rms_mm']:.4f} | "
            f"{f['max_filtered_minus_floor_mm']:.4f} | {f['unfiltered_rms_deg']:.4f} | "
            f"{f['filtered_rms_deg']:.5f} | {f['floor_rms_deg']:.5f} |"
        )
    lines += [
        "",
        f"The identifications are noise-free (0.01 mm display only) but for the row with "
        f"lengths of σ = {NOISE_MM} mm: there the floor is larger, and the filtered error "
        "follows it.",
        "",
    ]
    return "\n".join(lines)


def main() -> None:
    if "--markdown-only" in sys.argv:  # rewrite filter.md from filter.json
        got = json.loads((OUT / "filter.json").read_text())
        text = markdown(got["environment"], got["speed"], got["labels"], got["accuracy"])
        (OUT / "filter.md").write_text(text)
        print(text)
        return
    env = environment()
    cell = make_cell()
    against = None
    if "--against" in sys.argv:  # the previous checkout: a git revision
        against = sys.argv[sys.argv.index("--against") + 1]
    sp, labels = speeds(cell, against)
    if "--speed-only" in sys.argv:
        print(json.dumps({"environment": env, "speed": sp}, indent=2))
        return
    acc = accuracy(cell, make_cell(noise_mm=NOISE_MM))
    (OUT / "filter.json").write_text(
        json.dumps({"environment": env, "speed": sp, "labels": labels, "accuracy": acc}, indent=2)
        + "\n"
    )
    (OUT / "filter.md").write_text(markdown(env, sp, labels, acc))
    print((OUT / "filter.md").read_text())


if __name__ == "__main__":
    main()
