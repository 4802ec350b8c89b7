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
    and ``SPL``; the ``_REL`` moves are relative and have no target. The target is a
    declared name (own ``.dat`` first, then the ``GLOBAL`` data of the other given ``.dat``
    files; an index that is a variable uses every element) or an inline aggregate. A target
    used through the geometric operator (``XP1:F_OFS``) is not where the robot goes: it is
    left unchanged and named.

Frames (per move, in program order within each ``DEF``; unknown at its start)
    ``FDAT_ACT=FP1`` (the inline forms): the ``FDAT``'s ``TOOL_NO``/``BASE_NO`` (0: the
    flange / ``$WORLD``); ``$TOOL=TOOL_DATA[n]``, ``$BASE=BASE_DATA[n]``, ``BAS(#TOOL,n)``,
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
from dataclasses import dataclass, field
from pathlib import PurePath

import numpy as np

from calib.filter.krl_data import (
    AXIS_TYPES,
    Aggregate,
    DataFile,
    Decl,
    blank,
    index_text,
    parse_aggregate,
    read_declarations,
)
from calib.filter.rotations import frame, matrix_to_zyx_deg, zyx_deg_to_matrix
from calib.filter.sites import (
    Configuration,
    Correction,
    Edit,
    FilterInputError,
    FrameTables,
    Num,
    Source,
    Target,
    Use,
    edit,
)
from calib.kinematics import N_JOINTS, FloatArray

NAME = "krl"
EXTENSIONS = (".src", ".dat")
POSITION_DECIMALS = 3
ANGLE_DECIMALS = 4
JOINT_DECIMALS = 4
CARTESIAN_KEYS = ("X", "Y", "Z", "A", "B", "C")
JOINT_KEYS = tuple(f"A{j}" for j in range(1, N_JOINTS + 1))

_HEADER = re.compile(r"^(?:\s*&[^\n]*\n|\s*\n)*\s*(GLOBAL\s+)?(DEF|DEFFCT|DEFDAT)\b", re.I)
_ROUTINE = re.compile(r"^\s*(?:GLOBAL\s+)?(?:DEF|DEFFCT\s+\w+)\s+(\w+)\s*\(", re.I)
_END = re.compile(r"^\s*END(?:FCT)?\s*$", re.I)
_MOVE = re.compile(r"^\s*(PTP|LIN|CIRC|SPTP|SLIN|SCIRC|SPL)[ \t]+(.*)$", re.I)
_FDAT_ACT = re.compile(r"^\s*FDAT_ACT\s*=\s*([A-Za-z_$][\w$]*)\s*$", re.I)
_SET = re.compile(r"^\s*\$(TOOL|BASE)\s*=\s*(.*?)\s*$", re.I)
_BAS = re.compile(r"^\s*BAS\s*\(\s*#(TOOL|BASE)\s*,\s*(\d+)\s*\)", re.I)
_DATA_REF = re.compile(r"(TOOL_DATA|BASE_DATA)\s*\[\s*(\d+)\s*\]$", re.I)
_NAME_REF = re.compile(r"([A-Za-z_$][\w$]*)\s*(?:\[([^\]]*)\])?")
_OPEN = re.compile(r"^\s*(IF|SWITCH|FOR|WHILE|LOOP|REPEAT)\b", re.I)
_MIDDLE = re.compile(r"^\s*(ELSE|CASE|DEFAULT)\b", re.I)
_CLOSE = re.compile(r"^\s*(ENDIF|ENDSWITCH|ENDFOR|ENDWHILE|ENDLOOP|UNTIL)\b", re.I)
_FOLD = re.compile(r"^\s*;\s*(END)?FOLD\b([^;\r\n]*)", re.I)
_FOLD_FRAME = re.compile(r"\b(Tool|Base)\s*\[\s*(\d+)\s*\]", re.I)


@dataclass
class CartSite:
    """Where a Cartesian target's numbers are: ``X, Y, Z``, ``A, B, C``, and ``T``."""

    position: list[Num]
    angles: list[Num]
    turn: Num | None


@dataclass
class JointSite:
    joints: list[Num]


@dataclass
class _Frame:
    """The tool or base in force: its name, frame (None: unknown) and why unknown."""

    name: str
    value: FloatArray | None
    problem: str

    def same(self, other: _Frame) -> bool:
        if self.value is None or other.value is None:
            return self.value is None and other.value is None and self.problem == other.problem
        return self.name == other.name and bool(np.allclose(self.value, other.value))


def _unknown(why: str) -> _Frame:
    return _Frame("?", None, why)


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
    return Configuration(ranges, shoulder=-1 if si & 1 else 1, elbow=1 if si & 2 else -1,
                         wrist=-1 if si & 4 else 1, text=text)  # fmt: skip


def _frame_of(agg: Aggregate, what: str, src: Source) -> tuple[FloatArray | None, str]:
    vals = [agg.items.get(k) for k in CARTESIAN_KEYS]
    if any(v is None or v.num is None for v in vals):
        return None, f"{what} is not a full frame {{X,Y,Z,A,B,C}} ({src.name}:" \
                     f"{src.line_of(agg.start)})"
    x, y, z, a, b, c = (float(v.num) for v in vals)  # type: ignore[union-attr,arg-type]
    return frame(np.array([x, y, z]), zyx_deg_to_matrix(a, b, c)), ""


@dataclass
class _Program:
    """The files of one dialect run: ``.dat`` data and the ``.src`` sources."""

    data: dict[str, DataFile] = field(default_factory=dict)  # by file name
    srcs: list[Source] = field(default_factory=list)

    def own_dat(self, src_name: str) -> DataFile | None:
        stem = PurePath(src_name).with_suffix("").as_posix().lower()
        for name, df in self.data.items():
            if PurePath(name).with_suffix("").as_posix().lower() == stem:
                return df
        return None

    def lookup(self, name: str, src_name: str | None) -> Decl | None:
        """``name`` in the ``.src``'s own ``.dat`` first, then the GLOBAL (or undeclared-
        array) data of the others; None when absent or found in several."""
        key = name.upper()
        own = self.own_dat(src_name) if src_name else None
        if own is not None and key in own.decls:
            return own.decls[key]
        found = [df.decls[key] for df in self.data.values() if df is not own
                 and key in df.decls and (df.decls[key].is_global or src_name is None)]  # fmt: skip
        return found[0] if len(found) == 1 else None

    def table(self, which: str, n: int) -> _Frame:
        """``TOOL_DATA[n]`` or ``BASE_DATA[n]`` (0: the identity)."""
        label = f"{which}[{n}]"
        if n == 0:
            return _Frame(label, np.eye(4), "")
        types = [(df.tool_type if which == "TOOL_DATA" else df.base_type).get(n)
                 for df in self.data.values()]  # fmt: skip
        external = {"TOOL_DATA": "#BASE", "BASE_DATA": "#TCP"}[which]
        if external in types:
            kind = which.split("_")[0]
            return _unknown(f"{label}: external TCP ({kind}_TYPE[{n}]={external}) not supported")
        decl = self.lookup(which, None)
        agg = decl.elements.get((n,)) if decl is not None else None
        if agg is None:
            return _unknown(f"{label} is not in the given files (give $config.dat)")
        value, why = _frame_of(agg, label, self.data[decl.file].source)  # type: ignore[union-attr]
        return _Frame(label, value, why)


class KrlDialect:
    """The KRL dialect (see the module docstring)."""

    name = NAME
    extensions = EXTENSIONS

    def claims(self, source: Source) -> bool:
        """A ``DEF``/``DEFFCT`` (``.src``) or ``DEFDAT`` (``.dat``) after the ``&`` header."""
        m = _HEADER.match(blank(source.text).lstrip("\ufeff"))
        if not m:
            return False
        is_dat = PurePath(source.name).suffix.lower() == ".dat"
        return (m.group(2).upper() == "DEFDAT") == is_dat

    def parse(self, sources: Sequence[Source], frames: FrameTables) -> list[Target]:
        del frames  # KRL's frames are in $config.dat and the programs
        prog = _Program()
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
                items = [((), decl.value)] if decl.value is not None else list(
                    decl.elements.items())  # fmt: skip
                for index, agg in items:
                    assert agg is not None
                    t = self._target(df.source, decl.name + index_text(index), agg, decl.kind)
                    if t is not None:
                        targets[(df.source.name, t.name.upper())] = t
                        order.append(t)
                        if decl.kind == "FRAME":
                            frame_decls.add(id(t))
        for src in prog.srcs:
            order.extend(_Moves(self, prog, src, targets).run())
        # A FRAME declaration is a target only when a move uses it.
        return [t for t in order if t.uses or id(t) not in frame_decls]

    @staticmethod
    def _frame_names(prog: _Program) -> set[str]:
        """Names assigned to ``$TOOL``/``$BASE`` anywhere: frames, not targets."""
        out = {"TOOL_DATA", "BASE_DATA"}
        for src in prog.srcs:
            for line in blank(src.text).splitlines():
                m = _SET.match(line)
                if m:
                    r = _NAME_REF.fullmatch(m.group(2))
                    if r:
                        out.add(r.group(1).upper())
        return out

    def _target(self, src: Source, name: str, agg: Aggregate, kind: str) -> Target | None:
        """The target of an aggregate (None when it is neither a position nor axes)."""
        line = src.line_of(agg.start)
        keys = set(agg.items)
        if kind in AXIS_TYPES or (not kind and "A1" in keys):
            nums = [agg.num(src, k) for k in JOINT_KEYS]
            if any(n is None for n in nums):
                return Target(src.name, line, name, "joint", joints_deg=np.zeros(N_JOINTS),
                              problem="not all of A1..A6 are numbers", site=None)  # fmt: skip
            joints = [n for n in nums if n is not None]
            return Target(src.name, line, name, "joint",
                          joints_deg=np.array([n.value for n in joints]),
                          site=JointSite(joints))  # fmt: skip
        if not (kind or keys & set(CARTESIAN_KEYS)):
            return None
        nums = [agg.num(src, k) for k in CARTESIAN_KEYS]
        s_num, t_num = agg.num(src, "S"), agg.num(src, "T")
        text = " ".join(f"{k} {agg.items[k].text}" for k in ("S", "T") if k in agg.items)
        conf = configuration(s_num.value if s_num else None, t_num.value if t_num else None,
                             text)  # fmt: skip
        t = Target(src.name, line, name, "cartesian", pose=np.eye(4), configuration=conf)
        if any(n is None for n in nums):
            missing = [k for k, n in zip(CARTESIAN_KEYS, nums, strict=True) if n is None]
            t.problem = (f"{', '.join(missing)} not given: the controller takes them from the "
                         "current position")  # fmt: skip
            return t
        vals = [n.value for n in nums if n is not None]
        t.pose = frame(np.array(vals[:3]), zyx_deg_to_matrix(*vals[3:]))
        t.site = CartSite([n for n in nums[:3] if n], [n for n in nums[3:] if n], t_num)
        return t

    def render(self, target: Target, correction: Correction) -> list[Edit]:
        edits: list[Edit | None] = []
        if isinstance(target.site, JointSite):
            assert correction.joints_deg is not None
            for num, v in zip(target.site.joints, correction.joints_deg, strict=True):
                edits.append(edit(num, float(v), JOINT_DECIMALS))
            return [e for e in edits if e is not None]
        site: CartSite = target.site
        assert correction.pose is not None and correction.joints_deg is not None
        old = np.array([n.value for n in site.angles])
        abc = matrix_to_zyx_deg(correction.pose[:3, :3], near_deg=old)
        for num, v in zip(site.position, correction.pose[:3, 3], strict=True):
            edits.append(edit(num, float(v), POSITION_DECIMALS))
        for num, v in zip(site.angles, abc, strict=True):
            edits.append(edit(num, float(v), ANGLE_DECIMALS))
        if site.turn is not None:
            edits.append(_turn_edit(site.turn, correction.joints_deg))
        return [e for e in edits if e is not None]


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


class _Moves:
    """The moves of one ``.src``: their targets' uses, with the tool and base in force."""

    def __init__(self, dialect: KrlDialect, prog: _Program, src: Source,
                 targets: dict[tuple[str, str], Target]) -> None:  # fmt: skip
        self.dialect, self.prog, self.src, self.targets = dialect, prog, src, targets
        self.tool = _unknown("no tool set before this move in its DEF")
        self.base = _unknown("no base set before this move in its DEF")
        self.blocks: list[dict[str, object]] = []
        self.folds: list[tuple[int | None, int | None, int]] = []
        self.inline: list[Target] = []
        self.previous: Target | None = None

    def run(self) -> list[Target]:
        code = blank(self.src.text)
        raw_lines = self.src.text.split("\n")
        offset = 0
        for k, line in enumerate(code.split("\n")):
            self._fold(raw_lines[k], k + 1)
            self._statement(line, offset, k + 1)
            offset += len(line) + 1
        return self.inline

    def _fold(self, raw: str, line: int) -> None:
        m = _FOLD.match(raw)
        if not m:
            return
        if m.group(1):
            if self.folds:
                self.folds.pop()
            return
        found = {k.upper(): int(v) for k, v in _FOLD_FRAME.findall(m.group(2))}
        self.folds.append((found.get("TOOL"), found.get("BASE"), line))

    def _reset(self, why: str) -> None:
        self.tool = _unknown(f"no tool set before this move in {why}")
        self.base = _unknown(f"no base set before this move in {why}")
        self.blocks = []
        self.previous = None

    def _statement(self, line: str, offset: int, no: int) -> None:
        if m := _ROUTINE.match(line):
            self._reset(f"DEF {m.group(1)}")
        elif _END.match(line):
            self._reset("its DEF")
        elif m := _FDAT_ACT.match(line):
            self._fdat(m.group(1), no)
        elif m := _BAS.match(line):
            table = "TOOL_DATA" if m.group(1).upper() == "TOOL" else "BASE_DATA"
            self._set(m.group(1).upper(), self.prog.table(table, int(m.group(2))))
        elif m := _SET.match(line):
            self._set(m.group(1).upper(), self._frame_value(m.group(2), offset + m.start(2), no))
        elif _OPEN.match(line):
            self.blocks.append({"entry": (self.tool, self.base), "ends": [], "line": no,
                                "loop": _OPEN.match(line).group(1).upper()  # type: ignore[union-attr]
                                not in ("IF", "SWITCH")})  # fmt: skip
        elif _MIDDLE.match(line) and self.blocks:
            blk = self.blocks[-1]
            blk["ends"].append((self.tool, self.base))  # type: ignore[attr-defined]
            self.tool, self.base = blk["entry"]  # type: ignore[misc]
        elif _CLOSE.match(line) and self.blocks:
            self._close()
        elif m := _MOVE.match(line):
            self._move(m.group(1).upper(), m.group(2), offset + m.start(2), no)

    def _set(self, which: str, value: _Frame) -> None:
        if which == "TOOL":
            self.tool = value
        else:
            self.base = value

    def _close(self) -> None:
        blk = self.blocks.pop()
        entry = blk["entry"]
        ends = [*blk["ends"], (self.tool, self.base)]  # type: ignore[misc]
        ends.append(entry)  # a loop may run zero times; an IF may take no branch
        merged = []
        for k, what in ((0, "tool"), (1, "base")):
            first = ends[0][k]
            if all(first.same(e[k]) for e in ends[1:]):
                merged.append(first)
            else:
                merged.append(_unknown(f"the {what} differs between the paths through the block "
                                       f"at line {blk['line']}"))  # fmt: skip
        self.tool, self.base = merged[0], merged[1]

    def _fdat(self, name: str, no: int) -> None:
        decl = self.prog.lookup(name, self.src.name)
        if decl is None or decl.kind != "FDAT" or decl.value is None:
            why = f"FDAT {name} (line {no}) is not declared in the given .dat files"
            self.tool, self.base = _unknown(why), _unknown(why)
            return
        agg = decl.value
        ipo = agg.items.get("IPO_FRAME")
        nums = {k: agg.items[k].num for k in ("TOOL_NO", "BASE_NO") if k in agg.items}
        if ipo is not None and ipo.text.upper() == "#TCP":
            why = f"FDAT {name}: external TCP (IPO_FRAME #TCP) not supported"
            self.tool, self.base = _unknown(why), _unknown(why)
            return
        for key, table, which in (("TOOL_NO", "TOOL_DATA", "TOOL"), ("BASE_NO", "BASE_DATA",
                                                                        "BASE")):  # fmt: skip
            v = nums.get(key)
            if v is None:
                self._set(which, _unknown(f"FDAT {name} has no numeric {key}"))
            else:
                self._set(which, self.prog.table(table, int(v)))

    def _frame_value(self, expr: str, at: int, no: int) -> _Frame:
        if m := _DATA_REF.fullmatch(expr):
            return self.prog.table(m.group(1).upper(), int(m.group(2)))
        if expr.upper() in ("$NULLFRAME", "$WORLD"):
            return _Frame(expr.upper(), np.eye(4), "")
        if expr.startswith("{"):
            agg = parse_aggregate(blank(self.src.text), at, self.src)
            value, why = _frame_of(agg, f"the frame at line {no}", self.src)
            return _Frame(f"frame@{no}", value, why)
        r = _NAME_REF.fullmatch(expr)
        decl = self.prog.lookup(r.group(1), self.src.name) if r and not r.group(2) else None
        if decl is not None and decl.value is not None and decl.kind in ("FRAME", "POS", "E6POS"):
            value, why = _frame_of(decl.value, decl.name, self.prog.data[decl.file].source)
            return _Frame(decl.name, value, why)
        return _unknown(f"line {no}: {expr[:40]} cannot be resolved to a frame")

    def _move(self, kind: str, rest: str, at: int, no: int) -> None:
        """A move whose arguments ``rest`` start at offset ``at`` of the file."""
        n_targets = 2 if kind in ("CIRC", "SCIRC") else 1
        fold_problem = self._fold_check(no)
        tool, base = self.tool, self.base
        problem = "; ".join(p for p in (tool.problem, base.problem, fold_problem) if p)
        use = Use(self.src.name, no, tool.name, base.name, tool.value, base.value, problem)
        for a, b in _top_level_spans(rest)[:n_targets]:
            part = rest[a:b]
            lead = len(part) - len(part.lstrip())
            self._use_part(part.strip(), at + a + lead, use, no)

    def _fold_check(self, no: int) -> str:
        for tool_no, base_no, line in reversed(self.folds):
            if tool_no is None and base_no is None:
                continue
            for want, have, label in ((tool_no, self.tool, "TOOL_DATA"),
                                      (base_no, self.base, "BASE_DATA")):  # fmt: skip
                if want is None or have.value is None:
                    continue
                expect = f"{label}[{want}]"
                if have.name != expect:
                    return (f"the FOLD at line {line} says {label.split('_')[0].title()}[{want}] "
                            f"but {have.name} is in force")  # fmt: skip
            return ""
        return ""

    def _use_part(self, part: str, at: int, use: Use, no: int) -> None:
        if part.startswith("{"):
            code = blank(self.src.text)
            agg = parse_aggregate(code, at, self.src)
            t = self.dialect._target(self.src, f"inline@{no}", agg, "")
            if t is None:
                return
            self._chain(t)
            t.uses.append(use)
            self.inline.append(t)
            return
        m = _NAME_REF.match(part)
        if not m:
            return
        name, index = m.group(1), m.group(2)
        tail = part[m.end():].strip()
        expression = tail.startswith(":") or part.startswith(":")
        decl = self.prog.lookup(name, self.src.name)
        if decl is None:
            return
        owner = decl.file
        if index is None:
            keys = [name.upper()] if decl.value is not None else [
                (decl.name + index_text(i)).upper() for i in decl.elements]  # fmt: skip
        else:
            try:
                idx = tuple(int(v) for v in index.split(","))
                keys = [(decl.name + index_text(idx)).upper()]
            except ValueError:
                keys = [(decl.name + index_text(i)).upper() for i in decl.elements]
        for key in keys:
            t = self.targets.get((owner, key))
            if t is None:
                continue
            if expression:
                u = Use(use.file, use.line, use.tool_name, use.work_name, use.tool, use.work,
                        f"used in the expression {part[:40]!r}: the robot does not go to the "
                        "target itself")  # fmt: skip
                t.uses.append(u)
            else:
                self._chain(t)
                t.uses.append(use)

    def _chain(self, t: Target) -> None:
        """A Cartesian target without S and T takes the branch nearest the previous move's
        target (same file only: the core looks it up there)."""
        c = t.configuration
        if (t.kind == "cartesian" and c is not None and c.shoulder is None
                and np.all(np.isinf(c.joint_ranges_deg)) and self.previous is not None
                and self.previous.file == t.file and not t.uses):  # fmt: skip
            t.configuration = Configuration(after=self.previous.name, text="(none)")
        self.previous = t


def _top_level_spans(text: str) -> list[tuple[int, int]]:
    """Spans of ``text`` split at commas outside braces, brackets and parentheses."""
    out, depth, last = [], 0, 0
    for i, c in enumerate(text):
        if c in "{[(":
            depth += 1
        elif c in "}])":
            depth -= 1
        elif c == "," and depth == 0:
            out.append((last, i))
            last = i + 1
    out.append((last, len(text)))
    return out


DIALECT = KrlDialect()

__all__ = ["DIALECT", "KrlDialect", "configuration", "turn_of"]
