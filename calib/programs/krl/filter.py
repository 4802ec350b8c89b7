"""KUKA KRL dialect of the filter: ``.src``/``.dat`` pairs and ``$config.dat``.

Targets
    In a ``.dat``: ``E6POS``, ``POS`` and ``FRAME`` (Cartesian) and ``E6AXIS``, ``AXIS``
    (joints) declared with a value, with or without ``DECL``, ``GLOBAL`` or not, single or
    arrays (``DECL E6POS PATH[20]`` then ``PATH[3]={…}``: one target per element, named
    ``PATH[3]``). In a ``.src``: inline aggregates ``{X …}`` / ``{A1 …}`` of the moves. A
    Cartesian value is ``X, Y, Z`` [mm] and ``A, B, C`` [deg] with ``R = Rz(A)·Ry(B)·Rx(C)``;
    a joint value ``A1 … A6`` [deg]. External axes ``E1 … E6`` are never touched. A
    ``FRAME`` (no status or turn) is a target only when a move uses it; ``TOOL_DATA`` and
    ``BASE_DATA`` never are. A Cartesian value without all six of ``X … C`` is left
    unchanged and named (the controller fills the rest from the current position).

Moves
    ``PTP``, ``LIN``, ``CIRC`` (its auxiliary and end point), ``SPTP``, ``SLIN``, ``SCIRC``
    and ``SPL``. The target is a declared name (own ``.dat`` first, then the ``GLOBAL``
    data of the other given ``.dat`` files and everything ``$config.dat`` declares; an index
    that is a variable uses every element) or an inline aggregate. What a ``_REL`` move goes
    by is an offset, and a target used through the geometric operator (``XP1:F_OFS``) is
    not where the robot goes: both are left unchanged and named.

Frames (per move, in program order within each ``DEF``; unknown at its start)
    ``FDAT_ACT=FP1`` (the inline forms): the ``FDAT``'s ``TOOL_NO``/``BASE_NO`` (0: the
    flange / ``$WORLD``); the same from a ``WITH $TOOL = STOOL2(FP1), $BASE =
    SBASE(FP1.BASE_NO)`` clause (KSS 8.3 spline forms, on the move or its ``SPLINE``
    block); ``$TOOL=TOOL_DATA[n]``, ``$BASE=BASE_DATA[n]``, ``BAS(#TOOL,n)``,
    ``BAS(#BASE,n)``; ``$TOOL``/``$BASE`` set to an inline frame, a ``FRAME`` of the given
    ``.dat`` files or ``$NULLFRAME``. ``TOOL_DATA[n]``/``BASE_DATA[n]`` (``{X,Y,Z,A,B,C}``)
    come from the given ``.dat`` files (``$config.dat``). ``BASE_DATA`` is taken in the
    robot's base frame (``$ROBROOT`` at ``$WORLD``, the default). Where ``IF``/``SWITCH``
    branches or a loop body leave the tool or base different, the move after them has no
    known frame. An inline form's ``;FOLD`` line (``Tool[1]:grip Base[2]:table``) must agree
    with its ``FDAT``, else its move is refused with both. An external TCP (``IPO_FRAME
    #TCP``, ``BASE_TYPE[n]=#TCP``) is not supported: its targets are named.

Configuration (``S`` status, ``T`` turn), in KUKA's own joint angles
    ``T`` bit ``j`` set: axis ``j+1`` < 0, clear: >= 0. ``S`` bit 0 (:data:`S_OVERHEAD`) set:
    the wrist root point is behind axis 1 (overhead area; shoulder -1); bit 1
    (:data:`S_ELBOW_UP`) set: axis 3 above the line from axis 2 to the wrist root point (elbow
    +1); bit 2 (:data:`S_A5_NEGATIVE`) set: A5 < 0 (wrist -1). Higher bits are not read.
    Proven on real backups (docs/robots-kuka.md). ``S`` and ``T`` are never rewritten: a
    correction whose joints would have another ``T`` writes nothing. A ``POS``/``FRAME``
    without ``S`` and ``T`` takes the branch nearest the previous move's target, as the
    controller does. A joint target with ``|A5|`` < :data:`WRIST_SINGULARITY_DEG` is left
    as :data:`WRIST_SINGULARITY`; a Cartesian target with ``E1 … E6`` not 0 is left named.

Data files
    ``$config.dat`` is read (``TOOL_DATA``, ``BASE_DATA``, their types, global points such
    as ``XHOME``) and never written: its targets are left as :data:`CONFIG_DAT_READ_ONLY`.
    A ``.dat`` point that no move of the given ``.src`` files uses takes its tool and base
    from its own ``FDAT`` (``XP1`` → ``FP1``); without one it is left as :data:`UNUSED`.
    Both reasons are in :data:`NOT_LEFT_REASONS`: targets left on purpose.

Precision: positions to at least 3 decimals, ``A, B, C`` and joints to at least 4 (KRL
keeps a REAL: about 7 significant digits).
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache
from pathlib import PurePath

import numpy as np

from calib.kinematics import N_JOINTS, FloatArray
from calib.programs.formats import LANGUAGES
from calib.programs.krl.data import (
    AXIS_TYPES,
    CARTESIAN_KEYS,
    Aggregate,
    Program,
    blank,
    index_text,
    read_declarations,
)
from calib.programs.krl.moves import NAME_REF, SET_FRAME, Moves
from calib.programs.rotations import frames, matrix_to_zyx_deg, zyx_deg_to_matrix
from calib.programs.sites import (
    READ_ONLY_REASON,
    UNUSED_REASON,
    WRIST_SINGULARITY_DEG,
    WRIST_SINGULARITY_REASON,
    Configuration,
    Correction,
    Edit,
    FilterInputError,
    FrameTables,
    Num,
    Source,
    Target,
    Use,
    edits_for,
)

NAME = "krl"
EXTENSIONS = LANGUAGES[NAME].extensions
POSITION_DECIMALS = 3
ANGLE_DECIMALS = 4
JOINT_DECIMALS = 4
#: Characters of a file's beginning that must hold its ``&`` header and ``DEF``/``DEFDAT``.
HEADER_CHARS = 65536
JOINT_KEYS = tuple(f"A{j}" for j in range(1, N_JOINTS + 1))

#: ``S`` (status) bits, in KUKA's own joint angles (docs/robots-kuka.md has the sources and
#: the check on real programs). Bit 0 set: the wrist root point is behind axis 1 (negative x
#: in the A1 frame: KUKA's "overhead area"; shoulder -1).
S_OVERHEAD = 1
#: Bit 1 set: axis 3 above the line from axis 2 to the wrist root point (elbow +1).
S_ELBOW_UP = 2
#: Bit 2 set: A5 < 0 (wrist -1).
S_A5_NEGATIVE = 4
#: A joint target with ``|A5|`` below this [deg] is at the wrist singularity: A4 and A6 turn
#: about one line there, and a correction of a few hundredths of a millimetre would turn them
#: by degrees; it is left, named.
WRIST_SINGULARITY = f"{WRIST_SINGULARITY_REASON} (A5 = 0)"
#: The controller's own data file: read (TOOL_DATA, BASE_DATA, XHOME …), never written.
CONFIG_DAT = "$config.dat"
#: Reasons of targets left on purpose (the summary need not count them as left).
CONFIG_DAT_READ_ONLY = (
    f"{READ_ONLY_REASON}: $config.dat (its XHOME is the home position behind $IN_HOME)"
)
UNUSED = f"{UNUSED_REASON}: no FDAT of it names tool and base"
#: The reasons above, for the summary: a target left with one of them is not "left".
NOT_LEFT_REASONS = (CONFIG_DAT_READ_ONLY, UNUSED)
EXTERNAL_AXES = tuple(f"E{j}" for j in range(1, 7))

_HEADER = re.compile(r"^(?:\s*&[^\n]*\n|\s*\n)*\s*(GLOBAL\s+)?(DEF|DEFFCT|DEFDAT)\b", re.I)


@dataclass(slots=True)
class CartSite:
    """Where a Cartesian target's numbers are: ``X, Y, Z``, ``A, B, C``, and ``T``."""

    position: list[Num]
    angles: list[Num]
    turn: Num | None


@dataclass(slots=True)
class JointSite:
    joints: list[Num]


@lru_cache(maxsize=1024)
def configuration(s: float | None, t: float | None, text: str) -> Configuration:
    """The branch a KUKA controller takes for status ``s`` and turn ``t`` (see the module
    docstring); either may be None."""
    ranges = np.tile([-np.inf, np.inf], (N_JOINTS, 1))
    if t is not None:
        for j in range(N_JOINTS):
            ranges[j] = (-np.inf, 0.0) if int(t) >> j & 1 else (0.0, np.inf)
    if s is None:
        return Configuration(ranges, text=text)
    si = int(s)
    return Configuration(
        ranges,
        shoulder=-1 if si & S_OVERHEAD else 1,
        elbow=1 if si & S_ELBOW_UP else -1,
        wrist=-1 if si & S_A5_NEGATIVE else 1,
        text=text,
    )


def status_of(shoulder: int, elbow: int, wrist: int) -> int:
    """KUKA ``S`` (bits 0..2) of branch signs (see :func:`configuration`)."""
    return (
        (S_OVERHEAD if shoulder < 0 else 0)
        | (S_ELBOW_UP if elbow > 0 else 0)
        | (S_A5_NEGATIVE if wrist < 0 else 0)
    )


class KrlDialect:
    """The KRL dialect (see the module docstring)."""

    name = NAME
    extensions = EXTENSIONS

    def claims(self, source: Source) -> bool:
        """A ``DEF``/``DEFFCT`` (``.src``) or ``DEFDAT`` (``.dat``) after the ``&`` header."""
        m = _HEADER.match(blank(source.text[:HEADER_CHARS]).lstrip("\ufeff"))
        if not m:
            return False
        is_dat = PurePath(source.name).suffix.lower() == ".dat"
        return (m.group(2).upper() == "DEFDAT") == is_dat

    def parse(self, sources: Sequence[Source], frames: FrameTables) -> list[Target]:
        del frames  # KRL's frames are in $config.dat and the programs
        prog = Program()
        for src in sources:
            if not self.claims(src):
                what = "DEFDAT" if src.name.lower().endswith(".dat") else "DEF"
                raise FilterInputError(src.name, f"not a KRL file (no {what} after the header)", 1)
            if src.name.lower().endswith(".dat"):
                prog.data[src.name] = read_declarations(src)
            else:
                prog.srcs.append(src)
        frame_names = self._frame_names(prog)
        targets: dict[tuple[str, str], Target] = {}
        order: list[Target] = []
        frame_decls: set[int] = set()
        for df in prog.data.values():
            for decl in df.decls.values():
                if decl.kind in ("", "FDAT") or decl.name.upper() in frame_names:
                    continue
                items = (
                    [((), decl.value)] if decl.value is not None else list(decl.elements.items())
                )
                for index, agg in items:
                    assert agg is not None
                    t = self._target(df.source, decl.name + index_text(index), agg, decl.kind)
                    if t is not None:
                        targets[(df.source.name, t.name.upper())] = t
                        order.append(t)
                        if decl.kind == "FRAME":
                            frame_decls.add(id(t))
        for src in prog.srcs:
            order.extend(Moves(self._target, prog, src, targets).run())
        _fill_poses(order)
        # A FRAME declaration is a target only when a move uses it.
        out = [t for t in order if t.uses or id(t) not in frame_decls]
        for t in out:
            if is_config_dat(t.file):
                t.problem = CONFIG_DAT_READ_ONLY
            elif t.problem:
                continue
            elif (
                t.kind == "joint"
                and abs(float(np.asarray(t.joints_deg)[4])) < WRIST_SINGULARITY_DEG
            ):
                t.problem = WRIST_SINGULARITY
            elif not t.uses and t.kind == "cartesian":
                _own_frames(prog, t)
        return out

    @staticmethod
    def _frame_names(prog: Program) -> set[str]:
        """Names assigned to ``$TOOL``/``$BASE`` anywhere: frames, not targets."""
        out = {"TOOL_DATA", "BASE_DATA"}
        for src in prog.srcs:
            for line in prog.code_of(src).splitlines():
                m = SET_FRAME.match(line) if "$" in line else None
                if m:
                    r = NAME_REF.fullmatch(m.group(2))
                    if r:
                        out.add(r.group(1).upper())
        return out

    def _target(self, src: Source, name: str, agg: Aggregate, kind: str) -> Target | None:
        """The target of an aggregate (None when it is neither a position nor axes)."""
        line = src.line_of(agg.start)
        items = agg.items
        if kind in AXIS_TYPES or (not kind and "A1" in items):
            nums = [agg.num(src, k) for k in JOINT_KEYS]
            if any(n is None for n in nums):
                return Target(
                    src.name,
                    line,
                    name,
                    "joint",
                    joints_deg=np.zeros(N_JOINTS),
                    problem="not all of A1..A6 are numbers",
                    site=None,
                )
            joints = [n for n in nums if n is not None]
            q = np.array([n.value for n in joints])
            return Target(
                src.name,
                line,
                name,
                "joint",
                joints_deg=q,
                site=JointSite(joints),
            )
        if not (kind or any(k in items for k in CARTESIAN_KEYS)):
            return None
        nums = [agg.num(src, k) for k in CARTESIAN_KEYS]
        s_num, t_num = agg.num(src, "S"), agg.num(src, "T")
        text = " ".join(f"{k} {items[k].text}" for k in ("S", "T") if k in items)
        conf = configuration(s_num.value if s_num else None, t_num.value if t_num else None, text)
        t = Target(src.name, line, name, "cartesian", pose=np.eye(4), configuration=conf)
        if any(n is None for n in nums):
            missing = [k for k, n in zip(CARTESIAN_KEYS, nums, strict=True) if n is None]
            t.problem = (
                f"{', '.join(missing)} not given: the controller takes them from the "
                "current position"
            )
            return t
        t.site = CartSite([n for n in nums[:3] if n], [n for n in nums[3:] if n], t_num)
        moved = [k for k in EXTERNAL_AXES if (e := agg.num(src, k)) is not None and e.value != 0]
        if moved:
            t.problem = (
                f"external axes {', '.join(moved)} not 0: the robot's base or the work may "
                "move with them (not modelled)"
            )
        return t

    def render(self, target: Target, correction: Correction) -> list[Edit]:
        if is_config_dat(target.file):
            return []
        if isinstance(target.site, JointSite):
            assert correction.joints_deg is not None
            return edits_for(target.site.joints, correction.joints_deg.tolist(), JOINT_DECIMALS)
        site: CartSite = target.site
        assert correction.pose is not None and correction.joints_deg is not None
        if site.turn is not None and turn_of(correction.joints_deg) != int(site.turn.value):
            # The correction would change T: the target is left as it is (never written).
            return []
        old = [n.value for n in site.angles]
        abc = matrix_to_zyx_deg(correction.pose[:3, :3], near_deg=old).tolist()
        return [
            *edits_for(site.position, correction.pose[:3, 3].tolist(), POSITION_DECIMALS),
            *edits_for(site.angles, abc, ANGLE_DECIMALS),
        ]


@lru_cache(maxsize=256)
def is_config_dat(name: str) -> bool:
    """True for the controller's ``$config.dat`` (any folder, any case); cached: the filter
    asks once per target."""
    return PurePath(name.replace("\\", "/")).name.lower() == CONFIG_DAT.lower()


def _own_frames(prog: Program, t: Target) -> None:
    """An unused ``.dat`` point: its tool and base from its own ``FDAT`` (``XP1`` → ``FP1``,
    the inline forms' naming), else named :data:`UNUSED`."""
    df = prog.data.get(t.file)
    fdat = df.decls.get("F" + t.name.upper()[1:]) if df is not None and t.name[:1] in "Xx" else None
    items = fdat.value.items if fdat is not None and fdat.value is not None else {}
    tool_no, base_no = items.get("TOOL_NO"), items.get("BASE_NO")
    ipo = items.get("IPO_FRAME")
    if (
        fdat is None
        or tool_no is None
        or tool_no.num is None
        or base_no is None
        or base_no.num is None
        or (ipo is not None and ipo.text.upper() == "#TCP")
    ):
        t.problem = UNUSED
        return
    tool = prog.table("TOOL_DATA", int(tool_no.num))
    base = prog.table("BASE_DATA", int(base_no.num))
    problem = "; ".join(dict.fromkeys(p for p in (tool.problem, base.problem) if p))
    t.uses.append(Use(t.file, fdat.line, tool.name, base.name, tool.value, base.value, problem))


def _fill_poses(targets: list[Target]) -> None:
    """Every Cartesian target's pose from its numbers, all rotations at once."""
    cart = [t for t in targets if isinstance(t.site, CartSite)]
    if not cart:
        return
    xyz = np.array([[n.value for n in t.site.position] for t in cart])
    abc = np.array([[n.value for n in t.site.angles] for t in cart])
    poses = frames(xyz, zyx_deg_to_matrix(abc[:, 0], abc[:, 1], abc[:, 2]))
    for t, pose in zip(cart, poses, strict=True):
        t.pose = pose


def turn_of(joints_deg: FloatArray) -> int:
    """KUKA ``T`` of joints (6,) [deg]: bit ``j`` set where axis ``j+1`` is negative."""
    return sum(1 << j for j in range(N_JOINTS) if joints_deg[j] < 0)


DIALECT = KrlDialect()

__all__ = [
    "CONFIG_DAT_READ_ONLY",
    "DIALECT",
    "NOT_LEFT_REASONS",
    "S_A5_NEGATIVE",
    "S_ELBOW_UP",
    "S_OVERHEAD",
    "UNUSED",
    "WRIST_SINGULARITY",
    "KrlDialect",
    "configuration",
    "is_config_dat",
    "status_of",
    "turn_of",
]
