"""KUKA conventions checked on real controller backups (figures for bench/robots-kuka.md).

For each backup (a public repository fetched under /work/.mirror, read with git, never copied
into this repository), the arm's model is built from its own ``R1/Mada/$machine.dat``
(``$TIRORO``, ``$LENGTH_A``, ``$LENGTH_B``, ``$TX3P3``, ``$TFLWP``, ``$SOFTN_END``,
``$SOFTP_END``) in the layout of calib/robots/library/kuka-*.toml. Every ``E6POS`` of its
``.dat`` files with an ``FDAT`` of the same name (``X…`` → ``F…``, ``IPO_FRAME #BASE``) is
taken to the flange with ``$config.dat``'s ``TOOL_DATA``/``BASE_DATA`` and solved on the
model. A point *fits* when one nominal solution within the limits has the written ``T``
(bit k: axis k+1 < 0) and the written ``S`` bits 0..2 (calib.programs.krl.filter.status_of of its
branch). Each entry of :data:`VARIANTS` (one element of the layout changed) is counted the
same way, to show that the data decides it. Pairs: every E6AXIS whose FK, with an E6POS's own
FDAT frames, is within 0.05 mm of that E6POS, with its gaps under each variant. The library
files built from a backup's machine data are compared with the model built here.

Run: ``PYTHONPATH=$PWD python bench/robots_kuka.py`` (prints Markdown tables).
"""

from __future__ import annotations

import re
import subprocess
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from calib.conventions import IDENTITY
from calib.filter.branches import branch_signs, flange_frames, nominal_solutions
from calib.models import RobotModel, model_from_mapping
from calib.programs.krl.filter import status_of, turn_of
from calib.programs.rotations import frame, invert, rotation_angle_deg, zyx_deg_to_matrix

MIRROR = Path("/work/.mirror")
BACKUPS = (
    "Aleynikovich+Zinkerreka",
    "HugoDanielson+ChinaMilling",
    "Aleynikovich+errekaSmartPal",
    "Naqiu06+KUKA-Robotics",
    "khrzysio+KRC4_test",
    "luciagumbau228+TFG",
    "rawpython+kukaKRLmagic",
)
#: KUKA's joint senses against the library tables (A1 turns about the base's -Z).
DIRECTION = (-1, 1, 1, -1, 1, -1)
_NUM = r"([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)"


def _git(repo: Path, *args: str) -> str:
    out = subprocess.run(["git", "-C", str(repo), *args], capture_output=True, check=True)
    return out.stdout.decode("latin-1")


def _items(text: str) -> dict[str, str]:
    return {k.upper(): v for k, v in re.findall(r"([A-Za-z]\w*)\s+('[^']*'|[^,}\s]+)", text)}


def _value(v: str) -> float:
    if v.startswith("'B") or v.startswith("'b"):
        return float(int(v[2:-1] or "0", 2))
    return float(v)


def _frame(text: str) -> np.ndarray:
    d = {k: float(v) for k, v in _items(text).items() if k in "XYZABC"}
    return frame(np.array([d["X"], d["Y"], d["Z"]]), zyx_deg_to_matrix(d["A"], d["B"], d["C"]))


@dataclass
class Machine:
    name: str
    d1: float
    a1: float
    a2: float
    a3: float
    d4: float
    d6: float
    limits: list[tuple[float, float]]


def machine(mada: str) -> Machine:
    def one(key: str) -> str:
        m = re.search(rf"^\s*(?:\w+\s+)?{re.escape(key)}\s*=\s*(.*?)\s*(?:;|$)", mada, re.M | re.I)
        if m is None:
            raise ValueError(f"$machine.dat has no {key}")
        return m.group(1)

    name = re.search(r'\$TRAFONAME\[\]="([^"]*)"', mada).group(1)  # type: ignore[union-attr]
    tiroro, tflwp, tx3p3 = (_items(one(k)) for k in ("$TIRORO", "$TFLWP", "$TX3P3"))
    soft = [(float(one(f"$SOFTN_END[{j}]")), float(one(f"$SOFTP_END[{j}]"))) for j in range(1, 7)]
    return Machine(
        name,
        float(tiroro["Z"]),
        float(one("$LENGTH_A")),
        float(one("$LENGTH_B")),
        float(tx3p3["Z"]),
        float(tx3p3["X"]),
        float(tflwp["Z"]),
        soft,
    )


def model_of(
    m: Machine, a3_sign: float = 1.0, direction: tuple[int, ...] | None = None
) -> RobotModel:
    """The library layout (calib/robots/library/kuka-*.toml) for machine data ``m``: the
    table's last frame is ``$FLANGE``; KUKA's A1, A4, A6 turn against the table's z axes."""
    rows = [
        (0, 0, m.d1, 0),
        (-90, m.a1, 0, 0),
        (0, m.a2, 0, -90),
        (-90, a3_sign * m.a3, m.d4, 0),
        (90, 0, 0, 0),
        (-90, 0, m.d6, 180),
    ]
    joints = [
        {"alpha_deg": r[0], "a_mm": r[1], "d_mm": r[2], "theta_deg": r[3], "limits_deg": list(lim)}
        for r, lim in zip(rows, m.limits, strict=True)
    ]
    return model_from_mapping(
        {
            "name": m.name,
            "convention": "mdh",
            "joints": joints,
            "controller": {"maker": "kuka", "direction": list(direction or DIRECTION)},
        }
    )


@dataclass
class Point:
    file: str
    name: str
    pose: np.ndarray
    s: int
    t: int
    tool: int
    base: int


def _files(repo: Path) -> list[str]:
    return _git(repo, "ls-tree", "-r", "--name-only", "HEAD").split("\n")


def _root(repo: Path) -> str:
    """The folder holding ``R1/`` (``KRC/`` in most backups, the top in some)."""
    for f in _files(repo):
        m = re.fullmatch(r"(.*?)R1/Mada/\$machine\.dat", f, re.I)
        if m:
            return m.group(1)
    raise ValueError(f"{repo}: no R1/Mada/$machine.dat")


def points(repo: Path) -> tuple[list[Point], dict[int, np.ndarray], dict[int, np.ndarray], str]:
    files = _files(repo)
    root = _root(repo).lower()
    cfg_name = next(f for f in files if f.lower() == root + "r1/system/$config.dat")
    cfg = _git(repo, "show", f"HEAD:{cfg_name}")
    tools = {
        int(n): _frame(v) for n, v in re.findall(r"^TOOL_DATA\[(\d+)\]=\{([^}]*)\}", cfg, re.M)
    }
    bases = {
        int(n): _frame(v) for n, v in re.findall(r"^BASE_DATA\[(\d+)\]=\{([^}]*)\}", cfg, re.M)
    }
    tools[0] = bases[0] = np.eye(4)
    out: list[Point] = []
    for f in files:
        if not f.lower().endswith(".dat") or not f.lower().startswith(root + "r1/"):
            continue
        text = _git(repo, "show", f"HEAD:{f}")
        fdat = {
            n.upper(): _items(v)
            for n, v in re.findall(r"FDAT\s+(\w+)\s*=\s*\{([^}]*)\}", text, re.I)
        }
        for n, v in re.findall(r"E6POS\s+(\w+)\s*=\s*\{([^}]*)\}", text, re.I):
            it, fd = _items(v), fdat.get("F" + n.upper()[1:])
            if fd is None or "S" not in it or "T" not in it:
                continue
            if fd.get("IPO_FRAME", "#BASE").upper() != "#BASE":
                continue
            tn, bn = int(fd["TOOL_NO"]), int(fd["BASE_NO"])
            if tn not in tools or bn not in bases:
                continue
            out.append(Point(f, n, _frame(v), int(_value(it["S"])), int(_value(it["T"])), tn, bn))
    return out, tools, bases, cfg


def _table_limits(model: RobotModel) -> np.ndarray:
    """The model's limits (KUKA's angles) as table angles (6, 2) [deg]."""
    lim = np.asarray(model.joint_limits_deg, dtype=float)
    d = np.asarray(model.controller.direction, dtype=float)[:, None]
    return np.sort(lim * d, axis=1)


def fits(model: RobotModel, pts: list[Point], tools, bases, flange: np.ndarray) -> tuple[int, int]:
    """Points whose written T is met by a nominal solution, and of those whose S bits 0..2
    are met by the same solution."""
    if not pts:
        return 0, 0
    fl = np.array([bases[p.base] @ p.pose @ invert(tools[p.tool]) @ invert(flange) for p in pts])
    # The solver works in the table's angles; T and S are read in KUKA's.
    table = replace(model, controller=IDENTITY)
    table = replace(table, joint_limits_deg=_table_limits(model))
    sol = nominal_solutions(table, fl)
    q_kuka = model.controller.to_controller_deg(sol.joints_deg)
    n_t = n_st = 0
    for i, p in enumerate(pts):
        ok = np.flatnonzero(sol.valid[i])
        t_ok = [k for k in ok if turn_of(q_kuka[i, k]) == p.t]
        st_ok = [
            k
            for k in t_ok
            if status_of(sol.shoulder[i, k], sol.elbow[i, k], 1 if q_kuka[i, k, 4] >= 0 else -1)
            == p.s & 7
        ]
        n_t += bool(t_ok)
        n_st += bool(st_ok)
    return n_t, n_st


def _ry(deg: float) -> np.ndarray:
    return frame(np.zeros(3), zyx_deg_to_matrix(0.0, deg, 0.0))


#: The variants: (label, a3 sign, directions, $FLANGE in the table's last frame).
VARIANTS = (
    ("library layout", 1.0, DIRECTION, np.eye(4)),
    ("A3-A4 offset flipped", -1.0, DIRECTION, np.eye(4)),
    ("$FLANGE with X out (Ry 90)", 1.0, DIRECTION, _ry(90.0)),
    ("A6 direction +1", 1.0, (-1, 1, 1, -1, 1, 1), np.eye(4)),
    ("A4 direction +1", 1.0, (-1, 1, 1, 1, 1, -1), np.eye(4)),
    ("A1 direction +1", 1.0, (1, 1, 1, -1, 1, -1), np.eye(4)),
)


@dataclass
class Pair:
    """An E6AXIS and an E6POS of one backup that are the same position: the E6POS taken with
    its own FDAT's TOOL_DATA/BASE_DATA."""

    axis_file: str
    axis_name: str
    joints_deg: np.ndarray
    pos_file: str
    pos_name: str
    pose: np.ndarray
    tool: int
    base: int
    s_t_written: tuple[int, int]


def _gap(
    model: RobotModel, q: np.ndarray, tool: np.ndarray, base: np.ndarray, pose: np.ndarray
) -> tuple[float, float]:
    """Position [mm] and orientation [deg] gap between FK(q) with tool and base and ``pose``."""
    table = replace(model, controller=IDENTITY)
    fl = flange_frames(table, model.controller.to_table_deg(q[None]))[0]
    tcp = invert(base) @ fl @ tool
    angle = float(rotation_angle_deg(pose[None, :3, :3], tcp[None, :3, :3])[0])
    return float(np.linalg.norm(tcp[:3, 3] - pose[:3, 3])), angle


def pairs(repo: Path, model: RobotModel, limit_mm: float = 0.05) -> list[Pair]:
    """Every (E6AXIS, E6POS with an FDAT) of the backup within ``limit_mm`` (own frames)."""
    root = _root(repo).lower()
    pts, tools, bases, _ = points(repo)
    axes = []
    for f in _files(repo):
        if not f.lower().endswith(".dat") or not f.lower().startswith(root + "r1/"):
            continue
        text = _git(repo, "show", f"HEAD:{f}")
        for n, v in re.findall(r"E6AXIS\s+(\w+)\s*=\s*\{([^}]*)\}", text, re.I):
            it = _items(v)
            if all(f"A{j}" in it for j in range(1, 7)):
                q = np.array([float(it[f"A{j}"]) for j in range(1, 7)])
                axes.append((f[len(root) :], n, q))
    out = []
    for af, an, q in axes:
        for p in pts:
            gap_mm, _ = _gap(model, q, tools[p.tool], bases[p.base], p.pose)
            if gap_mm <= limit_mm:
                pf = p.file[len(root) :]
                out.append(Pair(af, an, q, pf, p.name, p.pose, p.tool, p.base, (p.s & 7, p.t)))
    return out


#: Library files built from a backup's machine data.
LIBRARY = Path(__file__).parents[1] / "calib" / "robots" / "library"
FROM_BACKUP = {
    "kuka-kr210-r2700-prime": "Aleynikovich+Zinkerreka",
    "kuka-kr210-r2700-2": "HugoDanielson+ChinaMilling",
    "kuka-kr6-r900": "Naqiu06+KUKA-Robotics",
}


def library_check() -> None:
    """Each library file against the model built from its backup's $machine.dat."""
    import tomllib

    print("| library file | backup | max FK difference over 1000 poses (mm) | limits equal |")
    print("|---|---|---|---|")
    rng = np.random.default_rng(0)
    q = rng.uniform(-170.0, 170.0, size=(1000, 6))
    for lib, name in FROM_BACKUP.items():
        repo = MIRROR / name / "repo"
        if not repo.exists():
            continue
        m = machine(_git(repo, "show", f"HEAD:{_root(repo)}R1/Mada/$machine.dat"))
        ref = model_of(m)
        got = model_from_mapping(tomllib.loads((LIBRARY / f"{lib}.toml").read_text()))
        diff = []
        for mod in (ref, got):
            table = replace(mod, controller=IDENTITY)
            diff.append(flange_frames(table, mod.controller.to_table_deg(q)))
        gap = float(np.max(np.abs(diff[0] - diff[1])))
        same = bool(np.allclose(ref.joint_limits_deg, got.joint_limits_deg))
        print(f"| {lib}.toml | {name.replace('+', '/')} | {gap:.2e} | {same} |")
    print()


def main() -> None:
    library_check()
    head = " | ".join(v[0] for v in VARIANTS)
    print(f"| backup | arm ($TRAFONAME) | points (tool 0) | {head} |")
    print("|---|---|---|" + "---|" * len(VARIANTS))
    for name in BACKUPS:
        repo = MIRROR / name / "repo"
        if not repo.exists():
            continue
        m = machine(_git(repo, "show", f"HEAD:{_root(repo)}R1/Mada/$machine.dat"))
        pts, tools, bases, _ = points(repo)
        flange_only = [p for p in pts if p.tool == 0]
        cells = []
        for _, sign, direction, flange in VARIANTS:
            model = model_of(m, sign, direction)
            _, st = fits(model, pts, tools, bases, flange)
            _, st0 = fits(model, flange_only, tools, bases, flange)
            cells.append(f"{st} ({st0})")
        repo_name = name.replace("+", "/")
        row = " | ".join(cells)
        print(f"| {repo_name} | {m.name} | {len(pts)} ({len(flange_only)}) | {row} |")
    print()
    heads = " | ".join(f"{v[0]}: mm, deg" for v in VARIANTS)
    print(f"| backup | E6AXIS | E6POS (its FDAT) | S, T written | S, T of the joints | {heads} |")
    print("|---|---|---|---|---|" + "---|" * len(VARIANTS))
    for name in BACKUPS:
        repo = MIRROR / name / "repo"
        if not repo.exists():
            continue
        m = machine(_git(repo, "show", f"HEAD:{_root(repo)}R1/Mada/$machine.dat"))
        model = model_of(m)
        _, tools, bases, _ = points(repo)
        for p in pairs(repo, model):
            table = replace(model, controller=IDENTITY)
            qt = model.controller.to_table_deg(p.joints_deg[None])
            sh, el, _ = branch_signs(table, qt)
            s_j = status_of(int(sh[0]), int(el[0]), 1 if p.joints_deg[4] >= 0 else -1)
            cells = []
            for _, sign, direction, flange in VARIANTS:
                variant = model_of(m, sign, direction)
                tool = invert(flange) @ tools[p.tool]
                mm, deg = _gap(variant, p.joints_deg, tool, bases[p.base], p.pose)
                cells.append(f"{mm:.4f}, {deg:.4f}")
            print(
                f"| {name.replace('+', '/')} | {p.axis_file} {p.axis_name} "
                f"{np.round(p.joints_deg, 2).tolist()} | {p.pos_file} {p.pos_name} "
                f"(TOOL_NO {p.tool}, BASE_NO {p.base}) | {p.s_t_written} "
                f"| {(s_j, turn_of(p.joints_deg))} | {' | '.join(cells)} |"
            )


if __name__ == "__main__":
    main()
