"""ABB RAPID dialect of the filter (``.mod``, ``.modx``, ``.prg``, ``.sys``).

Targets
    ``robtarget`` and ``jointtarget`` declared ``CONST``, ``PERS`` or ``VAR`` (optionally
    ``LOCAL`` / ``TASK``), on one line or over several, single or arrays (``{n}``,
    ``{n,m}``: one target per element, named ``p{2}``, ``p{1,3}``), and inline literals
    ``[[x,y,z],[q1,q2,q3,q4],[cf1,cf4,cf6,cfx],[eax…]]`` inside move instructions.
    A robtarget's value: position [mm], quaternion ``w, x, y, z``, configuration, external
    axes (never touched). A jointtarget: six robot axes [deg], external axes (untouched).
    A declaration whose value is not a literal (``:= Offs(p1, …)``, a PERS without value) is
    no target site: it has no numbers to correct.

Moves
    Every instruction whose name starts with ``Move``, ``Trigg``, ``Search``, ``Arc`` or
    ``Cap`` (``MoveL``, ``MoveJ``, ``MoveC``, ``MoveAbsJ``, ``MoveLDO``, ``TriggL``,
    ``SearchL``, ``ArcL``…). Its targets are the positional arguments that name a declared
    robtarget/jointtarget (``p10``, ``p10{3}``; a variable index ``p{i}`` uses every element),
    inline literals, and the first argument of ``Offs(…)`` / ``RelTool(…)`` (the target is
    corrected at its own pose). Its tool is the positional argument naming a tooldata
    (``tool0`` or declared in the given files), its work object the ``\\WObj:=`` option
    (``wobj0``, the base frame, without it).

Frames
    tooldata ``[robhold, [[x,y,z],[q1..q4]], load]``: the TCP in the flange frame.
    wobjdata ``[robhold, ufprog, ufmec, uframe, oframe]``: the work object is
    ``uframe · oframe``. A stationary tool (tooldata ``robhold`` FALSE, wobjdata ``robhold``
    TRUE) or a work object moved by a mechanical unit (``ufprog`` FALSE) is not supported:
    its targets are skipped and named.
    Names are looked up in the target's own file first, then in the other given files;
    RAPID is case-insensitive.

Configuration (ABB confdata ``[cf1, cf4, cf6, cfx]``)
    ``cf1, cf4, cf6``: the quadrants of axes 1, 4, 6 (``floor(q / 90°)``); ``cfx`` 0..7:
    wrist centre in front of / behind axis 1 (``cfx < 4`` front), above / below the lower
    arm (``cfx`` in 0, 1, 4, 5 above), axis 5 positive / negative (even = positive). The
    quadrants are written back from the corrected joints, ``cfx`` as it was.

Precision: positions to at least 3 decimals (rounding ≤ 0.0005 mm per axis), quaternion
components to at least 6 (≤ 1e-4°), joint angles to at least 4 (≤ 0.00005°).
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from calib.filter.rapid_syntax import (
    ROBTARGET,
    Node,
    blank,
    is_jointtarget,
    is_pose,
    is_robtarget,
    nums,
    parse_literal,
    pose,
    skip_space,
    split_options,
    statement_end,
)
from calib.filter.rotations import (
    frame,
    matrix_to_quat_wxyz,
    quat_wxyz_to_matrix,
)
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
    edits_for,
    split_args,
)
from calib.kinematics import FloatArray

NAME = "rapid"
EXTENSIONS = (".mod", ".modx", ".prg", ".sys")
POSITION_DECIMALS = 3
QUATERNION_DECIMALS = 6
JOINT_DECIMALS = 4

_DECL = re.compile(
    r"\b(?:(?:LOCAL|TASK)\s+)?(?:CONST|PERS|VAR)\s+(robtarget|jointtarget|tooldata|wobjdata)"
    r"\s+([A-Za-z]\w*)\s*(\{[^}]*\})?\s*(:=)?",
    re.IGNORECASE,
)
_MOVE = re.compile(r"(?<![\w.])((?:Move|Trigg|Search|Arc|Cap)\w*)(?=[ \t\r\n\\])", re.IGNORECASE)
_MODULE = re.compile(r"^\s*(?:%%%[\s\S]*?%%%\s*)?MODULE\s+\w+", re.IGNORECASE)
#: Values RAPID predefines.
PREDEFINED_TOOLS = {"tool0"}
PREDEFINED_WOBJS = {"wobj0"}


@dataclass
class RobSite:
    """Where a robtarget's numbers are: position (3), quaternion (4), confdata (4)."""

    position: list[Num]
    quaternion: list[Num]
    conf: list[Num]


@dataclass
class JointSite:
    """Where a jointtarget's six robot axes are."""

    joints: list[Num]


_OPEN = np.tile([-np.inf, np.inf], (6, 1))


def configuration(conf: Sequence[float]) -> Configuration:
    """The branch an ABB controller takes for confdata ``[cf1, cf4, cf6, cfx]``."""
    ranges = _OPEN.copy()
    for j, cf in zip((0, 3, 5), conf[:3], strict=True):
        ranges[j] = (90.0 * cf, 90.0 * cf + 90.0)
    cfx = int(conf[3])
    text = "[" + ",".join(f"{int(c)}" for c in conf) + "]"
    if not 0 <= cfx <= 7:
        return Configuration(ranges, text=text)
    return Configuration(
        ranges,
        shoulder=1 if cfx < 4 else -1,
        elbow=1 if cfx in (0, 1, 4, 5) else -1,
        wrist=1 if cfx % 2 == 0 else -1,
        text=text,
    )


@dataclass
class _Decl:
    kind: str  # robtarget, jointtarget, tooldata, wobjdata (lower case)
    name: str
    file: str
    line: int
    value: Node | None
    dims: tuple[int, ...]
    elements: dict[tuple[int, ...], Node] = field(default_factory=dict)
    fast: re.Match[str] | None = None  # a plain robtarget literal read by ROBTARGET


def _dims(text: str | None) -> tuple[int, ...]:
    if not text:
        return ()
    try:
        return tuple(int(v) for v in text.strip("{} \t").split(","))
    except ValueError:
        return (-1,)  # a dimension given by a constant name: elements still read by shape


def _elements(
    node: Node, depth: int, index: tuple[int, ...], out: dict[tuple[int, ...], Node]
) -> None:
    if depth == 0:
        out[index] = node
        return
    for k, item in enumerate(node.items or []):
        _elements(item, depth - 1, (*index, k + 1), out)


@dataclass
class _Module:
    source: Source
    code: str
    decls: dict[str, _Decl] = field(default_factory=dict)  # lower-case name
    frames: dict[tuple[str, str], tuple[FloatArray | None, str]] = field(default_factory=dict)
    lookups: dict[tuple[str, tuple[str, ...]], tuple[_Decl | None, str]] = field(
        default_factory=dict
    )


def _read_decls(mod: _Module) -> None:
    src, code = mod.source, mod.code
    for m in _DECL.finditer(code):
        kind, name, dims_text, assign = m.group(1).lower(), m.group(2), m.group(3), m.group(4)
        line = src.line_of(m.start())
        dims = _dims(dims_text)
        value = None
        fast = None
        if assign:
            i = skip_space(code, m.end())
            if kind == "robtarget" and not dims:
                fast = ROBTARGET.match(code, i)  # the common case: no Node tree needed
            if fast is None and i < len(code) and code[i] == "[":
                value = parse_literal(code, i, src)
        decl = _Decl(kind, name, src.name, line, value, dims, fast=fast)
        if value is not None:
            _elements(value, len(dims), (), decl.elements)
            check = {"robtarget": is_robtarget, "jointtarget": is_jointtarget}.get(kind)
            for index, node in decl.elements.items():
                if check is not None and not check(node):
                    raise FilterInputError(
                        src.name,
                        f"{kind} {name}{_index_text(index)}: not a {kind} literal",
                        src.line_of(node.start),
                    )
        key = name.lower()
        if key in mod.decls:
            raise FilterInputError(
                src.name, f"{name} declared twice (also line {mod.decls[key].line})", line
            )
        mod.decls[key] = decl


def _index_text(index: tuple[int, ...]) -> str:
    return "{" + ",".join(str(i) for i in index) + "}" if index else ""


_REF = re.compile(r"([A-Za-z]\w*)\s*(?:\{([^}]*)\})?\s*$")
_WRAP = re.compile(r"(?:Offs|RelTool)\s*\(", re.IGNORECASE)
#: The common move: a target name (with an index), speed, zone and tool, and \WObj.
_SIMPLE_MOVE = re.compile(
    r"\s+([A-Za-z]\w*(?:\{[^{}\[\]()]*\})?)\s*,\s*([A-Za-z]\w*)\s*,\s*([A-Za-z]\w*)\s*,"
    r"\s*([A-Za-z]\w*)\s*(?:\\\s*WObj\s*:=\s*([A-Za-z]\w*)\s*)?",
    re.IGNORECASE,
)


class RapidDialect:
    """The RAPID dialect (see the module docstring)."""

    name = NAME
    extensions = EXTENSIONS

    def claims(self, source: Source) -> bool:
        """A RAPID extension and a ``MODULE`` statement as the first code."""
        head = source.text[:65536]  # the header: comments and %%% blocks come first
        return bool(_MODULE.match(blank(head).lstrip("\ufeff")))

    def parse(self, sources: Sequence[Source], frames: FrameTables) -> list[Target]:
        del frames  # RAPID declares its frames in the program
        modules = []
        for src in sources:
            mod = _Module(src, blank(src.text))
            if not _MODULE.match(mod.code.lstrip("\ufeff")):
                raise FilterInputError(src.name, "not a RAPID module (no MODULE statement)", 1)
            _read_decls(mod)
            modules.append(mod)
        targets: dict[tuple[str, str], Target] = {}
        order: list[Target] = []
        for mod in modules:
            for decl in mod.decls.values():
                if decl.kind not in ("robtarget", "jointtarget"):
                    continue
                if decl.fast is not None:
                    t = self._target_fast(mod.source, decl.name, decl.fast)
                    targets[(mod.source.name, t.name.lower())] = t
                    order.append(t)
                for index, node in decl.elements.items():
                    t = self._target(
                        mod.source, f"{decl.name}{_index_text(index)}", decl.kind, node
                    )
                    targets[(mod.source.name, t.name.lower())] = t
                    order.append(t)
        for mod in modules:
            order.extend(self._moves(mod, modules, targets))
        return order

    # -- targets -----------------------------------------------------------------------
    def _target_fast(self, src: Source, name: str, m: re.Match[str]) -> Target:
        """A robtarget from :data:`ROBTARGET`'s groups (1-3 position, 4-7 quaternion, 8-11
        configuration; the external axes are never written)."""
        fname = src.name
        got = [
            Num(fname, m.start(g), m.end(g), m.group(g), float(m.group(g))) for g in range(1, 12)
        ]
        pos, quat, conf = got[:3], got[3:7], got[7:11]
        line = src.line_of(m.start())
        try:
            rot = quat_wxyz_to_matrix(np.array([n.value for n in quat]))
        except ValueError:
            raise FilterInputError(fname, f"{name}: quaternion of zero norm", line) from None
        return Target(
            fname,
            line,
            name,
            "cartesian",
            pose=frame(np.array([n.value for n in pos]), rot),
            configuration=configuration([n.value for n in conf]),
            site=RobSite(pos, quat, conf),
        )

    def _target(self, src: Source, name: str, kind: str, node: Node) -> Target:
        assert node.items is not None
        line = src.line_of(node.start)
        if kind == "jointtarget":
            joints = nums(node.items[0], src)
            return Target(
                src.name,
                line,
                name,
                "joint",
                joints_deg=np.array([n.value for n in joints]),
                site=JointSite(joints),
            )
        pos, quat, conf = (nums(node.items[k], src) for k in range(3))
        try:
            rot = quat_wxyz_to_matrix(np.array([n.value for n in quat]))
        except ValueError:
            raise FilterInputError(src.name, f"{name}: quaternion of zero norm", line) from None
        return Target(
            src.name,
            line,
            name,
            "cartesian",
            pose=frame(np.array([n.value for n in pos]), rot),
            configuration=configuration([n.value for n in conf]),
            site=RobSite(pos, quat, conf),
        )

    # -- moves -------------------------------------------------------------------------
    def _lookup(
        self, name: str, mod: _Module, modules: list[_Module], kinds: tuple[str, ...]
    ) -> tuple[_Decl | None, str]:
        memo = (name, kinds)
        if memo not in mod.lookups:
            mod.lookups[memo] = self._find(name, mod, modules, kinds)
        return mod.lookups[memo]

    def _find(
        self, name: str, mod: _Module, modules: list[_Module], kinds: tuple[str, ...]
    ) -> tuple[_Decl | None, str]:
        key = name.lower()
        d = mod.decls.get(key)
        if d is not None and d.kind in kinds:
            return d, ""
        found = [
            m.decls[key]
            for m in modules
            if m is not mod and key in m.decls and m.decls[key].kind in kinds
        ]
        if len(found) == 1:
            return found[0], ""
        if len(found) > 1:
            where = ", ".join(f"{d.file}:{d.line}" for d in found)
            return None, f"{name} is declared in several files ({where})"
        return None, ""

    def _frame_of(
        self, name: str, kind: str, mod: _Module, modules: list[_Module]
    ) -> tuple[FloatArray | None, str]:
        key = (name.lower(), kind)
        if key not in mod.frames:
            mod.frames[key] = self._resolve_frame(name, kind, mod, modules)
        return mod.frames[key]

    def _resolve_frame(
        self, name: str, kind: str, mod: _Module, modules: list[_Module]
    ) -> tuple[FloatArray | None, str]:
        if kind == "tooldata" and name.lower() in PREDEFINED_TOOLS:
            return np.eye(4), ""
        if kind == "wobjdata" and name.lower() in PREDEFINED_WOBJS:
            return np.eye(4), ""
        decl, why = self._lookup(name, mod, modules, (kind,))
        if decl is None:
            return None, why or f"{kind} {name} is not declared in the given files"
        node = decl.value
        if node is None or decl.dims:
            return None, f"{kind} {name} ({decl.file}:{decl.line}) has no literal value"
        items = node.items or []
        if kind == "tooldata":
            if len(items) != 3 or not is_pose(items[1]):
                where = f"{decl.file}:{decl.line}"
                return None, f"tooldata {name} ({where}) is not [robhold,tframe,load]"
            if items[0].word.upper() != "TRUE":
                return None, f"tooldata {name}: stationary tool (robhold FALSE) is not supported"
            return pose(items[1]), ""
        if len(items) != 5 or not (is_pose(items[3]) and is_pose(items[4])):
            return None, (
                f"wobjdata {name} ({decl.file}:{decl.line}) is not "
                "[robhold,ufprog,ufmec,uframe,oframe]"
            )
        if items[0].word.upper() != "FALSE":
            return None, f"wobjdata {name}: robot-held work object (robhold TRUE): not supported"
        if items[1].word.upper() != "TRUE":
            return None, f"wobjdata {name}: moved by a unit (ufprog FALSE): not supported"
        return pose(items[3]) @ pose(items[4]), ""

    def _moves(
        self, mod: _Module, modules: list[_Module], targets: dict[tuple[str, str], Target]
    ) -> list[Target]:
        """Record the uses of every move of ``mod``; returns its inline targets."""
        src, code = mod.source, mod.code
        inline: list[Target] = []
        for m in _MOVE.finditer(code):
            end = statement_end(code, m.end())
            line = src.line_of(m.start())
            tool_name, work_name = "", "wobj0"
            refs: list[tuple[str, Any]] = []  # ("name", (name, index)) or ("inline", Node)
            simple = _SIMPLE_MOVE.fullmatch(code, m.end(), end)
            args: list[tuple[str, int]] = []  # positional arguments and their offsets
            if simple is not None:  # "p, speed, zone, tool[\WObj:=w]": no splitting needed
                args = [(simple.group(g), simple.start(g)) for g in range(1, 5)]
                work_name = simple.group(5) or work_name
            else:
                for a, b in split_args(code, m.end(), end):
                    (pa, pb), opts = split_options(code, a, b)
                    for opt in opts:
                        key, _, val = opt.partition(":=")
                        if key.strip().lower() == "wobj":
                            work_name = val.strip()
                    raw = code[pa:pb]
                    arg = raw.strip()
                    if arg:
                        args.append((arg, pa + raw.find(arg[0])))
            for arg, astart in args:
                wrap = _WRAP.match(arg)
                if wrap:
                    inner = split_args(code, astart + wrap.end(), astart + len(arg) - 1)[0]
                    arg = code[inner[0] : inner[1]].strip()
                    astart = inner[0] + (
                        len(code[inner[0] : inner[1]]) - len(code[inner[0] : inner[1]].lstrip())
                    )
                if arg.startswith("["):
                    refs.append(("inline", parse_literal(code, astart, src)))
                    continue
                r = _REF.match(arg)
                if not r:
                    continue
                name, index = r.group(1), r.group(2)
                decl, _ = self._lookup(name, mod, modules, ("tooldata",))
                if decl is not None or name.lower() in PREDEFINED_TOOLS:
                    tool_name = name
                    continue
                refs.append(("name", (name, index)))
            if not refs:
                continue
            if tool_name:
                tool, why_t = self._frame_of(tool_name, "tooldata", mod, modules)
            else:
                tool, why_t = None, "no tooldata argument found"
            work, why_w = self._frame_of(work_name, "wobjdata", mod, modules)
            problem = "; ".join(w for w in (why_t, why_w) if w)
            use = Use(src.name, line, tool_name or "?", work_name, tool, work, problem)
            for kind, ref in refs:
                if kind == "inline":
                    node = ref
                    if is_robtarget(node):
                        t = self._target(
                            src, f"inline@{src.line_of(node.start)}", "robtarget", node
                        )
                    elif is_jointtarget(node):
                        t = self._target(
                            src, f"inline@{src.line_of(node.start)}", "jointtarget", node
                        )
                    else:
                        raise FilterInputError(
                            src.name,
                            "inline value is neither a robtarget nor a jointtarget",
                            src.line_of(node.start),
                        )
                    t.uses.append(use)
                    inline.append(t)
                    continue
                name, index = ref
                decl, _why = self._lookup(name, mod, modules, ("robtarget", "jointtarget"))
                if decl is None:
                    continue  # a speed, zone, signal, or a target declared elsewhere
                owner = decl.file
                if index is None or decl.dims == ():
                    keys = (
                        [name.lower()]
                        if not decl.dims
                        else [f"{decl.name}{_index_text(i)}".lower() for i in decl.elements]
                    )
                else:
                    try:
                        idx = tuple(int(v) for v in index.split(","))
                        keys = [f"{decl.name}{_index_text(idx)}".lower()]
                    except ValueError:  # a variable index: the move may use every element
                        keys = [f"{decl.name}{_index_text(i)}".lower() for i in decl.elements]
                for key in keys:
                    found = targets.get((owner, key))
                    if found is not None:
                        found.uses.append(use)
        return inline

    # -- writing -----------------------------------------------------------------------
    def render(self, target: Target, correction: Correction) -> list[Edit]:
        if isinstance(target.site, JointSite):
            assert correction.joints_deg is not None
            return edits_for(target.site.joints, correction.joints_deg, JOINT_DECIMALS)
        site: RobSite = target.site
        assert correction.pose is not None and correction.joints_deg is not None
        old_q = np.array([n.value for n in site.quaternion])
        quat = matrix_to_quat_wxyz(correction.pose[:3, :3], near=old_q)
        # An orientation that did not move (to the written precision) keeps its text even
        # where the file's quaternion was not of unit norm.
        if correction.shift_deg < 1e-5:
            quat = old_q
        edits = [
            *edits_for(site.position, correction.pose[:3, 3], POSITION_DECIMALS),
            *edits_for(site.quaternion, quat, QUATERNION_DECIMALS),
        ]
        for num, j in zip(site.conf[:3], (0, 3, 5), strict=True):
            cf = math.floor(float(correction.joints_deg[j]) / 90.0)
            if cf != num.value:  # a quadrant that did not change keeps its text
                edits.extend(edits_for([num], [cf], 0))
        return edits


DIALECT = RapidDialect()
