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

Configuration (``S`` status, ``T`` turn)
    ``T`` bit ``j`` set: axis ``j+1`` < 0, clear: ≥ 0 (the joint ranges). ``S`` bit 0 set:
    wrist centre behind axis 1 (overhead area; shoulder −1); bit 1 set: ``A3 ≥ φ``, axis 3
    above the line from axis 2 to the wrist centre (elbow +1); bit 2 set: ``A5 < 0``
    (wrist −1). ``S`` is written back as it was, ``T`` from the corrected joints (its
    ``'B…'`` or decimal form and digit count kept). A ``POS``/``FRAME`` without ``S`` and
    ``T`` takes the branch nearest the previous move's target, as the controller does.

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

from calib.filter.krl_data import (
    AXIS_TYPES,
    CARTESIAN_KEYS,
    Aggregate,
    Program,
    blank,
    index_text,
    read_declarations,
)
from calib.filter.krl_moves import NAME_REF, SET_FRAME, Moves
from calib.filter.rotations import frames, matrix_to_zyx_deg, zyx_deg_to_matrix
from calib.filter.sites import (
    Configuration,
    Correction,
    Edit,
    FilterInputError,
    FrameTables,
    Num,
    Source,
    Target,
    edits_for,
)
from calib.kinematics import N_JOINTS, FloatArray

NAME = "krl"
EXTENSIONS = (".src", ".dat")
POSITION_DECIMALS = 3
ANGLE_DECIMALS = 4
JOINT_DECIMALS = 4
#: Characters of a file's beginning that must hold its ``&`` header and ``DEF``/``DEFDAT``.
HEADER_CHARS = 65536
JOINT_KEYS = tuple(f"A{j}" for j in range(1, N_JOINTS + 1))

_HEADER = re.compile(r"^(?:\s*&[^\n]*\n|\s*\n)*\s*(GLOBAL\s+)?(DEF|DEFFCT|DEFDAT)\b", re.I)


@dataclass
class CartSite:
    """Where a Cartesian target's numbers are: ``X, Y, Z``, ``A, B, C``, and ``T``."""

    position: list[Num]
    angles: list[Num]
    turn: Num | None


@dataclass
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
        shoulder=-1 if si & 1 else 1,
        elbow=1 if si & 2 else -1,
        wrist=-1 if si & 4 else 1,
        text=text,
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
        return [t for t in order if t.uses or id(t) not in frame_decls]

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
            return Target(
                src.name,
                line,
                name,
                "joint",
                joints_deg=np.array([n.value for n in joints]),
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
        return t

    def render(self, target: Target, correction: Correction) -> list[Edit]:
        if isinstance(target.site, JointSite):
            assert correction.joints_deg is not None
            return edits_for(target.site.joints, correction.joints_deg.tolist(), JOINT_DECIMALS)
        site: CartSite = target.site
        assert correction.pose is not None and correction.joints_deg is not None
        old = [n.value for n in site.angles]
        abc = matrix_to_zyx_deg(correction.pose[:3, :3], near_deg=old).tolist()
        edits = [
            *edits_for(site.position, correction.pose[:3, 3].tolist(), POSITION_DECIMALS),
            *edits_for(site.angles, abc, ANGLE_DECIMALS),
        ]
        if site.turn is not None and (turn := _turn_edit(site.turn, correction.joints_deg)):
            edits.append(turn)
        return edits


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


def _turn_edit(num: Num, joints_deg: FloatArray) -> Edit | None:
    """``T`` from the corrected joints, written as the file wrote it."""
    new = turn_of(joints_deg)
    if int(num.value) == new:
        return None
    m = re.fullmatch(r"'([Bb])([01]*)'", num.text)
    if m:
        text = f"'{m.group(1)}{format(new, 'b').zfill(len(m.group(2)))}'"
    elif re.fullmatch(r"'[Hh][0-9A-Fa-f]*'", num.text):
        text = f"'{num.text[1]}{format(new, 'X').zfill(len(num.text) - 3)}'"
    else:
        text = str(new)
    return Edit(num.file, num.start, num.end, text)


DIALECT = KrlDialect()

__all__ = ["DIALECT", "KrlDialect", "configuration", "turn_of"]
