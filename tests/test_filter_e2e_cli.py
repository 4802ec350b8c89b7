"""The acceptance check of issue 25, end to end, on an EMULATED cell.

A true robot (DH errors, :func:`calib.synthetic.make_true_cell`) gives 200 cable lengths with a
little noise; ``cablecal identify`` turns them into RESULT.json (a subprocess). Programs are
planned offline on the nominal model in the four dialects, with 185–240 mm tools and work
objects / bases / user frames, each with one unreachable target, plus files without targets.
Then exactly ``cablecal filter RESULT.json FILES... --frames FRAMES.toml --robot MODEL --out
DIR`` runs as a subprocess, and DIR's files are read back and checked against the truth:
per dialect the corrected error is within 1.5× the floor + 0.005 mm and a tenth of the
unfiltered error, the orientation within 1.5× the floor + 0.002°; every byte outside the
targets' numbers is unchanged; the files without targets are copied unchanged; the
unreachable targets are left as they were and named in DIR/filter-summary.json.
"""

from __future__ import annotations

import dataclasses
import json
import os
import re
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from filter_cells import (
    DISPLAY_MM,
    HOOK_MM,
    Cell,
    planned_targets,
    rapid_module,
    regular_poses,
    smooth_path,
    tool_frame,
    urscript,
    work_frame,
)
from filter_olp import _executed, frames_toml, krl_program, ls_program, rms

from calib.filter.branches import flange_frames
from calib.filter.correct import calibration_from_result
from calib.filter.nearest import IK_OPTIONS
from calib.filter.run import EXIT_LEFT
from calib.ik import solve_ik
from calib.kinematics import FloatArray
from calib.models import HSR_JR680, model_from_mapping
from calib.programs.dialects import dialect_for
from calib.programs.rotations import invert, rotation_angle_deg
from calib.programs.sites import FrameTables, Num, Source, Target, parse_frames_toml
from calib.synthetic import TABLE_XII_D1, make_true_cell, random_poses_deg

#: Noise of the emulated lengths [mm] (1σ), before the display's 0.01 mm.
NOISE_MM = 0.02
_NUMBER = re.compile(rb"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")
#: Files without targets, in the four dialects.
NO_TARGETS = {
    "LOGIC.MOD": b"MODULE LOGIC\r\n  ! no targets here\r\n  PROC init()\r\n    SetDO do1, 1;\r\n"
    b"  ENDPROC\r\nENDMODULE\r\n",
    "io.script": b"def io():\n  set_digital_out(0, True)\n  sleep(0.5)\nend\n",
    "noop.src": b"&ACCESS RVP\r\nDEF noop( )\r\n  $OUT[1]=TRUE ; Greifer zu\r\nEND\r\n",
    "GRIP.LS": b"/PROG  GRIP\r\n/ATTR\r\nOWNER\t\t= MNEDITOR;\r\n/MN\r\n   1:  RO[1]=ON ;\r\n"
    b"/END\r\n",
}


@dataclass
class Program:
    """One dialect's planned program: its files, the plan and the frames it was planned in."""

    dialect: str
    files: dict[str, bytes]
    q_plan: FloatArray  # (n, 6) [deg]
    tool: FloatArray  # (4, 4) [mm]
    work: FloatArray  # (4, 4) [mm]


@dataclass
class Run:
    cell: Cell
    programs: dict[str, Program]
    frames: FrameTables
    out: Path
    code: int
    stdout: str
    summary: dict[str, Any]


def _cablecal() -> list[str]:
    exe = Path(sys.executable).parent / "cablecal"
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "daemon.cli"]


def _programs(nominal: Any) -> dict[str, Program]:
    work = work_frame()
    far = "[[4000,0,0],[1,0,0,0],[0,0,0,0],[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]]"
    q, tool = regular_poses(nominal, 30, seed=31), tool_frame(185.0)
    move = "        MoveL pFar, v200, fine, tOlp\\WObj:=wOlp;\r\n"
    mod = (
        rapid_module(nominal, q, tool, work, newline="\r\n")
        .replace("    PROC main()", f"    CONST robtarget pFar:={far};\r\n    PROC main()")
        .replace("    ENDPROC", f"{move}    ENDPROC")
    )
    # The tool and the work object declared in a system module of the task, as cells do.
    lines = mod.split("\r\n")
    cell_data = [ln for ln in lines if "tooldata" in ln or "wobjdata" in ln]
    sys_mod = "\r\n".join(["MODULE CELL_DATA(SYSMODULE)", *cell_data, "ENDMODULE", ""])
    mod = "\r\n".join(ln for ln in lines if ln not in cell_data)
    out = {
        "rapid": Program(
            "rapid",
            {"OLP_PATH.MOD": mod.encode(), "CELL_DATA.SYS": sys_mod.encode()},
            q,
            tool,
            work,
        )
    }
    q, tool = regular_poses(nominal, 30, seed=32), tool_frame(240.0)
    krl = krl_program(nominal, q, tool, work)
    krl["olp_path.dat"] = krl["olp_path.dat"].replace(
        "ENDDAT",
        "DECL E6POS XFAR={X 4000.0,Y 0.0,Z 0.0,A 0.0,B 0.0,C 0.0,S 2,T 0,E1 0.0,"
        "E2 0.0,E3 0.0,E4 0.0,E5 0.0,E6 0.0}\r\nDECL FDAT FFAR={TOOL_NO 3,BASE_NO 2,"
        "IPO_FRAME #BASE}\r\nENDDAT",
    )
    krl["olp_path.src"] = krl["olp_path.src"].replace(
        "PTP XHOME", "FDAT_ACT=FFAR\r\nLIN XFAR\r\nPTP XHOME"
    )
    out["krl"] = Program("krl", {k: v.encode("latin-1") for k, v in krl.items()}, q, tool, work)
    q, tool = regular_poses(nominal, 30, seed=33), tool_frame(200.0)
    script = urscript(nominal, q, tool).replace(
        "\nend\n", "\n  movel(p[4.0, 0.0, 0.0, 0.0, 3.1, 0.0], a=1.2, v=0.25)\nend\n"
    )
    out["urscript"] = Program("urscript", {"olp.script": script.encode()}, q, tool, np.eye(4))
    # A plain script: movel from target to target (each on the branch of the last).
    q, tool = smooth_path(nominal, 30, seed=35), tool_frame(230.0, tilt_deg=10.0)
    script = urscript(nominal, q, tool, polyscope=False).replace(
        "\nend\n", "\n  movel(p[4.0, 0.0, 0.0, 0.0, 3.1, 0.0], a=1.2, v=0.25)\nend\n"
    )
    out["urscript-path"] = Program("urscript", {"path.script": script.encode()}, q, tool, np.eye(4))
    q, tool = regular_poses(nominal, 30, seed=34), tool_frame(215.0, 30.0)
    ls = ls_program(nominal, q, tool, work).replace(
        "/END",
        "P[99]{\n   GP1:\n\tUF : 2, UT : 3,\t\tCONFIG : 'N U T, 0, 0, 0',\n"
        "\tX =   4000.000  mm,\tY =      0.000  mm,\tZ =      0.000  mm,\n"
        "\tW =      0.000 deg,\tP =      0.000 deg,\tR =      0.000 deg\n};\n/END",
    )
    out["fanuc-ls"] = Program("fanuc-ls", {"OLP_PATH.LS": ls.encode("ascii")}, q, tool, work)
    return out


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Run:
    tmp = tmp_path_factory.mktemp("e2e")
    model_path = tmp / "jr680-hook.json"
    model_path.write_text(json.dumps({**HSR_JR680, "tool_mm": list(HOOK_MM)}))
    nominal = model_from_mapping(json.loads(model_path.read_text()))
    errors = TABLE_XII_D1.copy()
    errors[0, 2] = errors[0, 3] = 0.0  # unobservable by cable lengths (filter_cells)
    errors[5] = 0.0
    truth = make_true_cell(nominal, dh_errors_deg_mm=errors)
    rng = np.random.default_rng(11)
    q = random_poses_deg(truth, 200, rng)
    lengths = truth.lengths_mm(q) + rng.normal(0.0, NOISE_MM, size=q.shape[0])
    lengths = np.round(lengths / DISPLAY_MM) * DISPLAY_MM
    rows = ["q1,q2,q3,q4,q5,q6,L"] + [
        ",".join(f"{v:.4f}" for v in [*qi, li]) for qi, li in zip(q, lengths, strict=True)
    ]
    (tmp / "lengths.csv").write_text("\n".join(rows) + "\n")
    result = tmp / "RESULT.json"
    ident = subprocess.run(
        [
            *_cablecal(),
            "identify",
            str(tmp / "lengths.csv"),
            "--robot",
            str(model_path),
            "--out",
            str(result),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert ident.returncode == 0, ident.stdout + ident.stderr
    cell = Cell(nominal, truth, json.loads(result.read_text()))
    programs = _programs(nominal)
    ls = programs["fanuc-ls"]
    (tmp / "FRAMES.toml").write_text(frames_toml(ls.tool, ls.work))
    src = tmp / "programs"
    src.mkdir()
    names: list[str] = []
    for files in [p.files for p in programs.values()] + [NO_TARGETS]:
        for name, data in files.items():
            (src / name).write_bytes(data)
            names.append(name)
    out = tmp / "DIR"
    cmd = [
        *_cablecal(),
        "filter",
        str(result),
        *(str(src / n) for n in names),
        "--frames",
        str(tmp / "FRAMES.toml"),
        "--robot",
        str(model_path),
        "--out",
        str(out),
    ]
    proc = subprocess.run(
        cmd, capture_output=True, text=True, timeout=120, env={**os.environ, "COLUMNS": "80"}
    )
    summary = json.loads((out / "filter-summary.json").read_text())
    frames = parse_frames_toml((tmp / "FRAMES.toml").read_text())
    return Run(cell, programs, frames, out, proc.returncode, proc.stdout + proc.stderr, summary)


def _nums(t: Target) -> list[Num]:
    """Every number of a target's site."""
    out: list[Num] = []
    for f in dataclasses.fields(t.site):
        v = getattr(t.site, f.name)
        out += (
            [v]
            if isinstance(v, Num)
            else [n for n in v if isinstance(n, Num)]
            if isinstance(v, list)
            else []
        )
    return out


def _outside(text: str, targets: list[Target], name: str) -> list[str]:
    """The text between the numbers of the targets (in file order)."""
    spans = sorted(
        (n.start, n.end) for t in targets if t.file == name and t.site is not None for n in _nums(t)
    )
    out, pos = [], 0
    for a, b in spans:
        out.append(text[pos:a])
        pos = b
    return [*out, text[pos:]]


def test_the_command_exits_3_and_writes_every_file(run: Run) -> None:
    assert run.code == EXIT_LEFT, run.stdout
    for p in run.programs.values():
        for name in p.files:
            assert (run.out / name).exists(), name
    for name, data in NO_TARGETS.items():
        assert (run.out / name).read_bytes() == data, name
    assert "left unchanged" in run.stdout
    assert all(len(line) <= 80 for line in run.stdout.splitlines())


@pytest.mark.parametrize("key", ["rapid", "krl", "urscript", "urscript-path", "fanuc-ls"])
def test_per_dialect_bytes_unreachable_and_accuracy(run: Run, key: str) -> None:
    prog = run.programs[key]
    dialect = prog.dialect
    before_src = [Source.from_bytes(n, d) for n, d in prog.files.items()]
    after_src = [Source.from_bytes(n, (run.out / n).read_bytes()) for n in prog.files]
    parser = dialect_for(before_src[0])
    assert parser.name == dialect
    before = parser.parse(before_src, run.frames)
    after = parser.parse(after_src, run.frames)
    assert [(t.file, t.name) for t in before] == [(t.file, t.name) for t in after]
    # Every byte outside the targets' numbers: the same text, the same encoding and line ends.
    for b, a in zip(before_src, after_src, strict=True):
        assert _outside(b.text, before, b.name) == _outside(a.text, after, a.name), b.name
        old, new = prog.files[b.name], (run.out / b.name).read_bytes()
        assert _NUMBER.sub(b"#", old) == _NUMBER.sub(b"#", new), b.name
        assert old.count(b"\r\n") == new.count(b"\r\n"), b.name
    rows = {(r["file"], r["name"]): r for r in run.summary["targets"]}
    # The unreachable target: left as it was, and named.
    far = [t for t in before if t.kind == "cartesian" and np.linalg.norm(t.pose[:3, 3]) > 3900.0]  # type: ignore[index]
    assert len(far) == 1
    row = rows[(far[0].file, far[0].name)]
    assert row["status"] == "unreachable", row
    after_far = next(t for t in after if t.name == far[0].name)
    assert [n.text for n in _nums(after_far)] == [n.text for n in _nums(far[0])]
    # Everything else corrected.
    others = [k for k, t in enumerate(before) if t is not far[0]]
    assert all(rows[(before[k].file, before[k].name)]["status"] == "corrected" for k in others)
    acc = _accuracy(run, prog, [before[k] for k in others], [after[k] for k in others])
    assert acc["filtered_mm"].size >= 30
    assert np.all(acc["filtered_mm"] <= 1.5 * acc["floor_mm"] + 0.005), acc
    assert rms(acc["filtered_mm"]) <= 0.1 * rms(acc["unfiltered_mm"])
    assert np.all(acc["filtered_deg"] <= 1.5 * acc["floor_deg"] + 0.002)
    assert rms(acc["unfiltered_mm"]) > 1.0  # the cell's error is there to be filtered


def _accuracy(
    run: Run, prog: Program, before: list[Target], after: list[Target]
) -> dict[str, FloatArray]:
    """Per corrected target (the joint targets at the flange, the Cartesian ones at the tool
    in their work object), the true robot's error against what was planned: unfiltered,
    filtered (DIR's numbers through the nominal controller on the written branch), and the
    floor (the calibrated model's exact joints)."""
    cell, nominal = run.cell, run.cell.nominal
    calibrated = calibration_from_result(cell.result, nominal).calibrated
    planned = planned_targets(nominal, prog.q_plan, prog.tool, prog.work)
    cart = [k for k, t in enumerate(before) if t.kind == "cartesian"]
    joint = [k for k, t in enumerate(before) if t.kind == "joint" and t.follows is None]
    # Which planned target each Cartesian one is (the written numbers round the plan).
    plan_of = [
        int(
            np.argmin(
                np.linalg.norm(
                    planned[:, :3, 3] - before[k].pose[:3, 3],  # type: ignore[index]
                    axis=1,
                )
            )
        )
        for k in cart
    ]
    intended = np.concatenate(
        [
            planned[plan_of],
            flange_frames(nominal, np.array([before[k].joints_deg for k in joint]).reshape(-1, 6)),
        ]
    )
    assert np.allclose(
        intended[: len(cart), :3, 3],
        [before[k].pose[:3, 3] for k in cart],  # type: ignore[index]
        atol=0.01,
    )
    tool = np.stack([prog.tool] * len(cart) + [np.eye(4)] * len(joint))
    work = np.stack([prog.work] * len(cart) + [np.eye(4)] * len(joint))
    seeds = np.concatenate(
        [prog.q_plan[plan_of], np.array([before[k].joints_deg for k in joint]).reshape(-1, 6)]
    )

    def err(q: FloatArray) -> tuple[FloatArray, FloatArray]:
        got = invert(work) @ cell.true_flange(q) @ tool
        return (
            np.linalg.norm(got[:, :3, 3] - intended[:, :3, 3], axis=1),
            rotation_angle_deg(intended[:, :3, :3], got[:, :3, :3]),
        )

    def executed(ts: list[Target]) -> FloatArray:
        if prog.dialect != "urscript":
            return _executed(cell, [ts[k] for k in cart] + [ts[k] for k in joint])[1]
        fl = np.stack([ts[k].pose @ invert(prog.tool) for k in cart])  # type: ignore[operator]
        by_name = {t.name: t for t in ts}
        if all(ts[k].name.endswith("_p") for k in cart):
            # PolyScope: movej(get_inverse_kin(Waypoint_n_p, qnear=Waypoint_n_q)).
            near = np.array([by_name[ts[k].name[:-1] + "q"].joints_deg for k in cart])
            out: FloatArray = solve_ik(
                nominal, near, fl[:, :3, 3], fl[:, :3, :3], np.zeros(3), IK_OPTIONS
            ).joints_deg
            return out
        # movel from the joints of the last move (the first from the movej before it).
        q_prev = np.asarray(ts[joint[0]].joints_deg) if joint else prog.q_plan[0]
        rows = []
        for f in fl:
            q_prev = solve_ik(
                nominal, q_prev[None], f[None, :3, 3], f[None, :3, :3], np.zeros(3), IK_OPTIONS
            ).joints_deg[0]
            rows.append(q_prev)
        return np.concatenate(
            [np.array(rows), np.array([ts[k].joints_deg for k in joint]).reshape(-1, 6)]
        )

    flange = work @ intended @ invert(tool)
    q_star = solve_ik(
        calibrated, seeds, flange[:, :3, 3], flange[:, :3, :3], np.zeros(3), IK_OPTIONS
    ).joints_deg
    out: dict[str, FloatArray] = {}
    for which, q in (
        ("unfiltered", executed(before)),
        ("filtered", executed(after)),
        ("floor", q_star),
    ):
        assert np.all(np.isfinite(q)), f"{which}: the controller finds no solution"
        out[f"{which}_mm"], out[f"{which}_deg"] = err(q)
    return out
