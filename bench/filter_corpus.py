"""Issue 34's acceptance of ``cablecal filter``, measured on real public programs.

The programs are not in this repository. bench/filter_corpus_manifest.py names each one
(repository, commit, paths, arm); get them with::

    git clone https://github.com/OWNER/NAME /some/where/OWNER+NAME/repo   # one per repository
    PYTHONPATH=. python -m bench.filter_corpus fetch /work/corpus --mirrors /some/where

(``--mirrors`` holds ``OWNER+NAME/repo`` git directories; default /work/.mirror, where the
session's ``fetch`` tool puts them). ``fetch`` writes each program's files to
``CORPUS/<id>/`` with ``git show COMMIT:PATH``, the KUKA ``$machine.dat`` and the Fanuc
``SYSFRAME.VA`` under ``CORPUS/<id>/aux/``. Then::

    PYTHONPATH=. python -m bench.filter_corpus run /work/corpus [--only ID,ID]

runs ``cablecal filter`` (the CLI, in-process through typer's runner: exit code, output files,
``filter-summary.json``) on each program with its arm's model file (``--robot NAME`` of the
library, or a TOML built from the backup's ``$machine.dat``; Fanuc: ``--frames`` from its
backup's ``SYSFRAME.VA``) and a result.json holding the calibrated table:

(a) calibrated = nominal: exit 0 or 3, no traceback, every output file byte-identical;
(b) nominal + joint 1's d + 0.3 mm, and nominal + joint 1's θ + 0.05°: each output is read
    back with the dialect's own parser; a corrected Cartesian target must be
    ``W⁻¹ G⁻¹ W T`` (``G`` the base shift or turn, ``W`` its work object) to 0.002 mm and
    0.001°, with its configuration text unchanged; a joint target ``q′`` must put the
    calibrated flange where the nominal one was at ``q`` (0.002 mm), and under the turn change
    only joint 1, by 0.05° (in the controller's sign); a seed (a PolyScope ``Waypoint_n_q``
    that only seeds its ``_p``, no move of its own) must change as its target's joints did;
(c) a realistic calibration (each DH entry + N(0, |Table XII D1 entry|), seed 34): the share
    of the targets that a move uses and that (a) found reachable (corrected) which are
    corrected; every non-number token unchanged and every changed number on a line of a
    corrected target (token streams diffed); ``$config.dat`` byte-identical;
(d) ``--only`` an unknown name, the program's text under another dialect's extension, an
    empty file: each exit 2, no traceback.

``python -m bench.filter_corpus report`` writes the .md again from the .json. The what-ifs
of the manifest (``WHAT_IFS``) run with ``--what-if`` or when ``--only`` names them.

Writes bench/filter_corpus.json and bench/filter_corpus.md (the tables; the findings the
.md ends with, after :data:`FINDINGS`, are written by hand and kept).
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
import tempfile
import traceback
from collections import Counter
from dataclasses import fields, replace
from pathlib import Path
from typing import Any

import numpy as np
from typer.testing import CliRunner

from bench.filter_corpus_manifest import PROGRAMS, WHAT_IFS, Program
from bench.robots_fanuc_check import _FRAME
from bench.robots_kuka import machine, model_of
from calib.conventions import IDENTITY
from calib.export import model_to_toml
from calib.filter.kin import flange_frames
from calib.models import RobotModel, builtin_model
from calib.programs.dialects import dialect_for
from calib.programs.rotations import invert, rotation_angle_deg
from calib.programs.sites import (
    EXTERNAL_AXIS_REASON,
    Dialect,
    FilterInputError,
    FrameTables,
    Source,
    Target,
    parse_frames_toml,
)
from calib.synthetic import TABLE_XII_D1
from daemon.cli import app

OUT = Path(__file__).parent
#: The .md's hand-written reading of a run starts at this line; ``run`` keeps it.
FINDINGS = "<!-- findings: hand-written, kept by `run` -->"
SHIFT_MM = 0.3
TURN_DEG = 0.05
TOL_MM = 0.002
TOL_DEG = 0.001
#: A seed's joint change against its target's, as the summary rounds joints [deg].
SEED_TOL_DEG = 2e-4
SEED = 34
OTHER_EXT = {"rapid": ".ls", "krl": ".mod", "fanuc": ".script", "urscript": ".src"}
_NUMBER = re.compile(r"[-+]?(?:\d+\.\d*|\.\d+|\d+)(?:[eE][-+]?\d+)?")


def fetch(corpus: Path, mirrors: Path) -> None:
    for p in PROGRAMS:
        git = mirrors / p.repo.replace("/", "+") / "repo"
        where = corpus / p.id
        (where / "aux").mkdir(parents=True, exist_ok=True)
        extra = [p.frames] if p.frames else []
        if p.arm.startswith("mada:"):
            extra.append(p.arm.removeprefix("mada:"))
        for path in (*p.paths, *extra):
            into = (where / "aux" if path in extra else where) / Path(path).name
            blob = subprocess.run(
                ["git", "--git-dir", str(git), "show", f"{p.commit}:{path}"],
                capture_output=True,
                check=True,
            ).stdout
            into.write_bytes(blob)
        print(f"{p.id}: {len(p.paths)} file(s)")


def nominal_of(p: Program, where: Path) -> RobotModel:
    if p.arm.startswith("mada:"):
        text = (where / "aux" / "$machine.dat").read_bytes().decode("latin-1")
        return replace(model_of(machine(text)), name=f"kuka-{p.id}")
    return builtin_model(p.arm)


def frames_toml(where: Path) -> str:
    """``--frames`` of a Fanuc backup's SYSFRAME.VA (group 1's user frames and tools)."""
    text = (where / "aux" / "SYSFRAME.VA").read_bytes().decode("latin-1")
    out = []
    for var, table in (("MNUFRAME", "uframe"), ("MNUTOOL", "utool")):
        m = re.search(r"\$" + var + r"\s+Storage.*?\n(.*?)\n\[\*", text, re.S)
        for e in _FRAME.finditer(m.group(1) if m else ""):
            v = [float(x) for x in e.groups()[1:]]
            out.append(f"[{table}.{int(e.group(1))}]\nxyz_mm = {v[:3]}\nwpr_deg = {v[3:]}\n")
    return "\n".join(out)


def result_json(nominal: RobotModel, table: np.ndarray) -> dict[str, Any]:
    """A result.json holding ``table`` as the calibrated DH table of ``nominal``."""
    dh = [
        dict(zip(("alpha_deg", "a_mm", "d_mm", "theta_deg"), map(float, r), strict=True))
        for r in table
    ]
    return {
        "robot": nominal.name,
        "convention": nominal.convention,
        "dh": dh,
        "tool_mm": [float(v) for v in nominal.tool_mm],
        **nominal.controller_fields(),
    }


def cli(args: list[Any]) -> dict[str, Any]:
    """``cablecal ARGS`` in-process: exit code and a traceback, if any."""
    r = CliRunner().invoke(app, [str(a) for a in args])
    tb = ""
    if r.exception is not None and not isinstance(r.exception, SystemExit):
        tb = "".join(traceback.format_exception(r.exception))[-600:]
    text = r.output + (r.stderr if r.stderr_bytes is not None else "")
    return {"exit": r.exit_code, "traceback": tb, "tail": text[-400:]}


class Case:
    """One program, its files and its models, run through the CLI."""

    def __init__(self, p: Program, corpus: Path, tmp: Path) -> None:
        self.p, self.where, self.tmp = p, corpus / (p.files_of or p.id), tmp
        self.files = [self.where / Path(f).name for f in p.paths]
        self.nominal = nominal_of(p, self.where)
        if p.no_external_axes:
            ctrl = self.nominal.controller
            if "external_axes" not in {f.name for f in fields(ctrl)}:
                raise ValueError("this code's model has no [controller] external_axes")
            ctrl = replace(ctrl, external_axes=0)  # type: ignore[call-arg]
            self.nominal = replace(self.nominal, controller=ctrl)
        if p.arm.startswith("mada:") or p.no_external_axes:
            robot = tmp / "robot.toml"
            robot.write_text(model_to_toml(self.nominal), encoding="utf-8")
            self.robot = str(robot)
        else:
            self.robot = p.arm
        self.frame_args: list[str] = []
        self.frames = FrameTables()
        if p.frames or p.frames_toml:
            text = p.frames_toml or frames_toml(self.where)
            (tmp / "frames.toml").write_text(text, encoding="utf-8")
            self.frame_args = ["--frames", str(tmp / "frames.toml")]
            self.frames = parse_frames_toml(text)
        self.inputs = {f.name: f.read_bytes() for f in self.files}

    def run(self, tag: str, table: np.ndarray, extra: list[str] | None = None) -> dict[str, Any]:
        res = self.tmp / f"{tag}.json"
        res.write_text(json.dumps(result_json(self.nominal, table)), encoding="utf-8")
        out = self.tmp / f"out-{tag}"
        args = ["filter", res, *self.files, "--out", out, "--robot", self.robot, *self.frame_args]
        r = cli(args + (extra or []))
        r["outputs"] = {f: (out / f).read_bytes() for f in self.inputs if (out / f).exists()}
        summary = out / "filter-summary.json"
        r["summary"] = json.loads(summary.read_text()) if summary.exists() else None
        return r

    def parse(self, data: dict[str, bytes]) -> list[Target]:
        """The targets of ``data`` as the dialects read them (a file a dialect refuses is
        dropped, as the filter drops it)."""
        by: dict[str, tuple[Dialect, list[Source]]] = {}
        for n, b in data.items():
            s = Source.from_bytes(n, b)
            try:
                d = dialect_for(s)
            except FilterInputError:
                continue
            by.setdefault(d.name, (d, []))[1].append(s)
        out: list[Target] = []
        for d, group in by.values():
            while group:
                try:
                    out.extend(d.parse(group, self.frames))
                    break
                except FilterInputError as exc:
                    group = [s for s in group if s.name != exc.file]
        return out


def _key(t: Target | dict[str, Any]) -> tuple[str, int, str]:
    if isinstance(t, dict):
        return (t["file"], t["line"], t["name"])
    return (t.file, t.line, t.name)


def _conf(t: Target) -> str:
    c = t.configuration
    return "" if c is None else f"{c.text}|{c.joint_ranges_deg.tolist()}"


def check_b(case: Case, kind: str) -> dict[str, Any]:
    """(b): the pure shift or turn of the whole arm, read back from the output text."""
    table = case.nominal.dh_table.copy()
    g = np.eye(4)
    if kind == "shift":
        table[0, 2] += SHIFT_MM
        g[2, 3] = SHIFT_MM
    else:
        table[0, 3] += TURN_DEG
        a = np.deg2rad(TURN_DEG)
        g[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
    r = case.run(kind, table)
    out: dict[str, Any] = {"exit": r["exit"], "traceback": r["traceback"]}
    if r["summary"] is None or r["traceback"]:
        out["error"] = r["tail"]
        return out
    calibrated = replace(case.nominal, dh_table=table)
    before = {_key(t): t for t in case.parse(case.inputs)}
    after = {_key(t): t for t in case.parse(r["outputs"])}
    done = [row for row in r["summary"]["targets"] if row["status"] == "corrected"]
    fails: list[str] = []
    pos_err, rot_err, jnt = [], [], []
    n_cart = n_joint = n_seed = 0
    rows_by_name = {(x["file"], x["name"]): x for x in done}
    for row in done:
        t0, t1 = before.get(_key(row)), after.get(_key(row))
        if t0 is None or t1 is None:
            fails.append(f"{row['file']}:{row['line']} {row['name']}: not read back")
            continue
        where = f"{row['file']}:{row['line']} {row['name']}"
        if t0.kind == "cartesian":
            assert t0.pose is not None and t1.pose is not None
            n_cart += 1
            w = t0.uses[0].work if t0.uses and t0.uses[0].work is not None else np.eye(4)
            want = invert(w) @ invert(g) @ w @ t0.pose
            e_mm = float(np.linalg.norm(t1.pose[:3, 3] - want[:3, 3]))
            e_deg = float(rotation_angle_deg(t1.pose[:3, :3], want[:3, :3]))
            pos_err.append(e_mm)
            rot_err.append(e_deg)
            if e_mm > TOL_MM or e_deg > TOL_DEG:
                moved = float(np.linalg.norm(t1.pose[:3, 3] - t0.pose[:3, 3]))
                fails.append(
                    f"{where}: off the expected target by {e_mm:.4f} mm, {e_deg:.5f} deg "
                    f"(moved {moved:.4f} mm)"
                )
            if _conf(t0) != _conf(t1):
                fails.append(
                    f"{where}: configuration {_conf(t0)} -> {_conf(t1)}; joints "
                    f"{row.get('nominal_joints_deg')} -> {row.get('joints_deg')}"
                )
        elif t0.follows and not t0.uses:
            # a seed (PolyScope's Waypoint_n_q: qnear of its _p, no move of its own): it
            # takes the joint change of the target it follows
            assert t0.joints_deg is not None and t1.joints_deg is not None
            n_seed += 1
            led = rows_by_name.get((t0.file, t0.follows))
            if led is None or led.get("joints_deg") is None:
                fails.append(f"{where}: follows {t0.follows}, which was not corrected")
                continue
            want_dq = np.subtract(led["joints_deg"], led["nominal_joints_deg"])
            off = float(np.max(np.abs(t1.joints_deg - t0.joints_deg - want_dq)))
            if off > SEED_TOL_DEG:
                fails.append(f"{where}: seed moved {off:.5f} deg off {t0.follows}'s change")
        else:
            assert t0.joints_deg is not None and t1.joints_deg is not None
            n_joint += 1
            f_nom = flange_frames(case.nominal, t0.joints_deg[None])[0]
            f_cal = flange_frames(calibrated, t1.joints_deg[None])[0]
            e_mm = float(np.linalg.norm(f_nom[:3, 3] - f_cal[:3, 3]))
            dq = t1.joints_deg - t0.joints_deg
            jnt.append(dq.tolist())
            pos_err.append(e_mm)
            if e_mm > TOL_MM:
                fails.append(f"{where}: flange off by {e_mm:.4f} mm (dq {np.round(dq, 5)})")
            if kind == "turn" and (
                np.max(np.abs(dq[1:])) > 1e-3 or abs(abs(dq[0]) - TURN_DEG) > 1e-3
            ):
                fails.append(f"{where}: joints changed by {np.round(dq, 5).tolist()}")
    out.update(
        corrected=len(done),
        cartesian=n_cart,
        joint=n_joint,
        seeds=n_seed,
        max_mm=max(pos_err, default=0.0),
        max_deg=max(rot_err, default=0.0),
        joint_dq=jnt[:2],
        fails=fails,
    )
    return out


def token_diff(a: str, b: str, lines: set[int]) -> tuple[int, int, int]:
    """(non-number tokens changed, numbers changed on a corrected target's line, elsewhere)."""
    na, nb = _NUMBER.split(a), _NUMBER.split(b)
    if na != nb:
        return 1 + sum(x != y for x, y in zip(na, nb, strict=False)), 0, 0
    inside = outside = 0
    starts_a = [m for m in _NUMBER.finditer(a)]
    starts_b = [m for m in _NUMBER.finditer(b)]
    for ma, mb in zip(starts_a, starts_b, strict=True):
        if ma.group() != mb.group():
            line = a.count("\n", 0, ma.start()) + 1
            if line in lines:
                inside += 1
            else:
                outside += 1
    return 0, inside, outside


def check_c(case: Case, a_rows: list[dict[str, Any]]) -> dict[str, Any]:
    rng = np.random.default_rng(SEED)
    table = case.nominal.dh_table + rng.normal(0.0, 1.0, (6, 4)) * np.abs(TABLE_XII_D1)
    r = case.run("realistic", table)
    out: dict[str, Any] = {"exit": r["exit"], "traceback": r["traceback"]}
    if r["summary"] is None or r["traceback"]:
        out["error"] = r["tail"]
        return out
    rows = r["summary"]["targets"]
    reach = {_key(x) for x in a_rows if x["status"] == "corrected"}
    used = [x for x in rows if x["status"] == "corrected" or not _program_reason(x["reason"])]
    n_used = sum(1 for x in used if x["status"] == "corrected")
    done = [x for x in rows if x["status"] == "corrected"]
    in_reach = [x for x in rows if _key(x) in reach]
    left = Counter(x["group"] for x in in_reach if x["status"] != "corrected")
    lines: dict[str, set[int]] = {}
    for x in done:
        for v in x.get("values", []):
            lines.setdefault(x["file"], set()).add(v["line"])
    skel = inside = outside = 0
    config_same = True
    for name, data in case.inputs.items():
        new = r["outputs"].get(name)
        if new is None:
            continue
        if name.lower() == "$config.dat":
            config_same = new == data
        enc = "utf-8" if _utf8(data) else "latin-1"
        s, i, o = token_diff(data.decode(enc), new.decode(enc), lines.get(name, set()))
        skel, inside, outside = skel + s, inside + i, outside + o
    out.update(
        targets=len(rows),
        used=len(used),
        reachable_a=len(in_reach),
        corrected=len(done),
        corrected_of_reachable=sum(1 for x in in_reach if x["status"] == "corrected"),
        left_reachable=dict(left.most_common()),
        share=(sum(1 for x in in_reach if x["status"] == "corrected") / len(in_reach))
        if in_reach
        else None,
        corrected_of_used=n_used,
        share_used=n_used / len(used) if used else None,
        skeleton_changed=skel,
        numbers_changed=inside,
        numbers_changed_elsewhere=outside,
        config_dat_identical=config_same,
    )
    return out


def _utf8(b: bytes) -> bool:
    try:
        b.decode("utf-8")
    except UnicodeDecodeError:
        return False
    return True


#: Reasons of the program itself (no move reaches it, or not the arm's own target: a track
#: or positioner moves with it, or its value is on the controller): outside ``share_used``.
_PROGRAM_REASONS = (
    "not used by any move",
    "in a file that is read and never written",
    "on an external axis",
    EXTERNAL_AXIS_REASON,  # main's wording since 57f670d
    "a position register",
    "GP1 has extended axes",
)


def _program_reason(reason: str) -> bool:
    return reason.startswith(_PROGRAM_REASONS)


def check_d(case: Case) -> dict[str, Any]:
    nominal = case.nominal.dh_table
    out: dict[str, Any] = {}
    r = case.run("d-only", nominal, ["--only", "NoSuchTarget_cablecal"])
    out["unknown_only"] = {"exit": r["exit"], "traceback": r["traceback"]}
    main = case.files[0]
    other = case.tmp / ("looks_" + main.stem + OTHER_EXT[case.p.language])
    other.write_bytes(main.read_bytes())
    empty = case.tmp / ("empty" + main.suffix)
    empty.write_bytes(b"")
    for tag, f in (("other_dialect", other), ("empty", empty)):
        res = case.tmp / "d.json"
        res.write_text(json.dumps(result_json(case.nominal, nominal)), encoding="utf-8")
        args = ["filter", res, f, "--out", case.tmp / f"out-d-{tag}", "--robot", case.robot]
        r2 = cli(args + case.frame_args)
        out[tag] = {"exit": r2["exit"], "traceback": r2["traceback"], "tail": r2["tail"][-200:]}
    return out


def check_old_file(case: Case) -> dict[str, Any]:
    """(a) with the arm as an old model file: the same table without a ``[controller]``
    table (the format before issue 34), given as a file to ``--robot``."""
    old = replace(case.nominal, controller=IDENTITY, name=case.nominal.name + "-old")
    path = case.tmp / "old-robot.toml"
    path.write_text(model_to_toml(old), encoding="utf-8")
    res = case.tmp / "old.json"
    res.write_text(json.dumps(result_json(old, old.dh_table)), encoding="utf-8")
    out = case.tmp / "out-old"
    r = cli(["filter", res, *case.files, "--out", out, "--robot", path, *case.frame_args])
    same = all((out / n).exists() and (out / n).read_bytes() == b for n, b in case.inputs.items())
    return {"exit": r["exit"], "traceback": r["traceback"], "identical": same}


def run_program(p: Program, corpus: Path) -> dict[str, Any]:
    with tempfile.TemporaryDirectory(prefix="cablecal-corpus-") as tmp:
        case = Case(p, corpus, Path(tmp))
        a = case.run("nominal", case.nominal.dh_table)
        ident = {n: a["outputs"].get(n) == b for n, b in case.inputs.items()}
        rows = a["summary"]["targets"] if a["summary"] else []
        counts = a["summary"]["counts"] if a["summary"] else {}
        groups = a["summary"]["left_by_reason"] if a["summary"] else {}
        errors = a["summary"]["errors"] if a["summary"] else []
        return {
            "id": p.id,
            "language": p.language,
            "source": {"repo": p.repo, "commit": p.commit, "paths": list(p.paths)},
            "arm": p.arm if not p.arm.startswith("mada:") else case.nominal.name,
            "arm_source": p.arm_source,
            "what": p.what,
            "targets": counts.get("targets", 0),
            "valid": p.valid,
            "a": {
                "exit": a["exit"],
                "traceback": a["traceback"],
                "identical": all(ident.values()),
                "not_identical": [n for n, ok in ident.items() if not ok],
                "counts": counts,
                "left_by_reason": groups,
                "errors": errors,
                "tail": a["tail"] if a["exit"] not in (0, 3) else "",
            },
            "a_old_file": check_old_file(case),
            "b_shift": check_b(case, "shift"),
            "b_turn": check_b(case, "turn"),
            "c": check_c(case, rows),
            "d": check_d(case),
        }


def main(argv: list[str]) -> None:
    cmd, corpus = argv[0], Path(argv[1] if len(argv) > 1 else ".")
    if cmd == "report":  # the .md again from the .json (e.g. after a change of the layout)
        doc = json.loads((OUT / "filter_corpus.json").read_text(encoding="utf-8"))
        write_markdown("filter_corpus", doc)
        return
    if cmd == "fetch":
        mirrors = Path(argv[argv.index("--mirrors") + 1]) if "--mirrors" in argv else None
        fetch(corpus, mirrors or Path("/work/.mirror"))
        return
    only = argv[argv.index("--only") + 1].split(",") if "--only" in argv else None
    results = []
    programs = (*PROGRAMS, *WHAT_IFS) if only or "--what-if" in argv else PROGRAMS
    for p in programs:
        if only and p.id not in only:
            continue
        try:
            res = run_program(p, corpus)
        except Exception as exc:  # the bench goes on; the failure is reported
            res = {"id": p.id, "language": p.language, "bench_error": repr(exc)}
        results.append(res)
        print(json.dumps({k: res.get(k) for k in ("id", "targets")}), flush=True)
    # the code under test: the branch's base on main (bench files are all a branch adds)
    commit = subprocess.run(
        ["git", "merge-base", "HEAD", "main"], capture_output=True, text=True, cwd=OUT
    ).stdout.strip()
    doc = {"commit": commit, "programs": results}
    name = "filter_corpus" if not only else "filter_corpus_partial"
    (OUT / f"{name}.json").write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
    write_markdown(name, doc)


def write_markdown(name: str, doc: dict[str, Any]) -> None:
    """``bench/NAME.md`` from a run's document, keeping the hand-written findings."""
    from bench.filter_corpus_report import markdown

    md = OUT / f"{name}.md"
    kept = md.read_text(encoding="utf-8").partition(FINDINGS)[2] if md.exists() else ""
    text = markdown(doc) + (f"\n{FINDINGS}{kept}" if kept else "")
    md.write_text(text, encoding="utf-8")


if __name__ == "__main__":
    main(sys.argv[1:])
