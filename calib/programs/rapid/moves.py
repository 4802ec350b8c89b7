"""RAPID moves for the filter: their arguments, tools and work objects, and the
configuration monitoring (``ConfL``/``ConfJ``) in force at each along the program's flow.

Moves
    Every instruction whose name starts with ``Move``, ``Trigg``, ``Search``, ``Arc`` or
    ``Cap`` (``MoveL``, ``MoveJ``, ``MoveC``, ``MoveAbsJ``, ``MoveLDO``, ``TriggL``,
    ``SearchL``, ``ArcL``…). Its targets are the positional arguments that name a
    robtarget/jointtarget in scope (``p10``, ``p10{3}``; a variable index ``p{i}`` uses every
    element), inline robtarget/jointtarget literals, and the first argument of ``Offs(…)`` /
    ``RelTool(…)`` (the target is corrected at its own pose); an inline literal of another
    type (``[v,200,v,200]``, a speeddata) is no target. Its tool is the positional argument
    at the instruction's tool position (:data:`TOOL_ARGUMENT`; for others the argument
    naming a tooldata, else the last one), its work object the ``\\WObj:=`` option
    (``wobj0``, the base frame, without it).

Configuration monitoring (ABB, RAPID reference manual, "Basic characteristics – Robot
configuration", and the instructions ``ConfL``/``ConfJ``)
    ``ConfL`` governs linear and circular moves (``MoveL``, ``MoveC``, ``TriggL`` …),
    ``ConfJ`` axis-wise moves (``MoveJ``, ``TriggJ`` …). With ``\\On`` (the default) a move to
    a robtarget takes the programmed configuration (confdata); with ``\\Off`` the controller
    ignores it and takes the solution closest to where the robot is, which along a program
    is the previous move's target. The setting holds until changed: it is tracked along each
    routine in program order, into the routines it calls (``Path_10;``), and is ``\\On`` at
    the start of ``main`` (PP to main resets it). A routine that the given files never call
    starts ``\\On`` when no file switches monitoring off anywhere, else unknown; a routine
    called with different settings starts unknown. The previous target of a routine's first
    move is the last one before the routine's call, where it is called from one place only.
"""

from __future__ import annotations

import re
from collections import defaultdict
from dataclasses import dataclass, field
from typing import Any

from calib.programs.rapid.decls import Module, lookup
from calib.programs.rapid.syntax import (
    is_jointtarget,
    is_robtarget,
    parse_literal,
    split_options,
    statement_end,
)
from calib.programs.sites import FilterInputError, split_args

MOVE = re.compile(r"(?<![\w.])((?:Move|Trigg|Search|Arc|Cap)\w*)(?=[ \t\r\n\\])", re.IGNORECASE)
_MOTION = re.compile(r"(?:Move|Trigg|Search|Arc|Cap)([LJC])", re.IGNORECASE)
_CONF = re.compile(r"(?<![\w.])Conf([LJ])\s*\\\s*(On|Off)\b", re.IGNORECASE)
_CALL = re.compile(r"(?m)^[ \t]*([A-Za-z]\w*)[ \t]*(?=;|[ \t]+[^\s:=])")
_REF = re.compile(r"([A-Za-z]\w*)\s*(?:\{([^}]*)\})?\s*$")
_NAME = re.compile(r"[A-Za-z]\w*")
_WRAP = re.compile(r"(?:Offs|RelTool)\s*\(", re.IGNORECASE)
#: The common move: a target name (with an index), speed, zone and tool, and \WObj.
_SIMPLE_MOVE = re.compile(
    r"\s+([A-Za-z]\w*(?:\{[^{}\[\]()]*\})?)\s*,\s*([A-Za-z]\w*)\s*,\s*([A-Za-z]\w*)\s*,"
    r"\s*([A-Za-z]\w*)\s*(?:\\\s*WObj\s*:=\s*([A-Za-z]\w*)\s*)?",
    re.IGNORECASE,
)
#: The tool's place among the positional arguments (0-based), from the instructions'
#: syntax in ABB's RAPID reference (``MoveL ToPoint, Speed, Zone, Tool``; ``MoveC CirPoint,
#: ToPoint, …``; ``TriggL ToPoint, Speed, Trigg_1, Zone, Tool``; ``SearchL Signal,
#: SearchPoint, ToPoint, Speed, Tool``).
TOOL_ARGUMENT = {
    **dict.fromkeys(("movel", "movej", "moveabsj", "moveldo", "movejdo", "movelsync"), 3),
    **dict.fromkeys(("movejsync", "movelao", "movejao", "movelgo", "movejgo"), 3),
    **dict.fromkeys(("movec", "movecdo", "movecsync", "movecao", "movecgo"), 4),
    **dict.fromkeys(("triggl", "triggj", "searchl", "searchj"), 4),
    **dict.fromkeys(("triggc", "searchc"), 5),
}
#: The target arguments (0-based) of the instructions in :data:`TOOL_ARGUMENT` (ToPoint;
#: MoveC's CirPoint and ToPoint; SearchL's ToPoint after Signal and SearchPoint, which the
#: search writes): an inline literal there must be a robtarget (a jointtarget for
#: MoveAbsJ).
TARGET_ARGUMENTS = {
    **dict.fromkeys(("movec", "movecdo", "movecsync", "movecao", "movecgo", "triggc"), (0, 1)),
    **dict.fromkeys(("searchl", "searchj"), (2,)),
    "searchc": (2, 3),
}
#: Moves that leave the robot where it is (external axes only).
ROBOT_STILL = {"moveextj"}
PREDEFINED_TOOLS = {"tool0"}
PREDEFINED_WOBJS = {"wobj0"}
#: Monitoring states: programmed configuration honoured, ignored, not known.
ON, OFF, UNKNOWN = "on", "off", "?"


@dataclass
class Move:
    """One move: where (``routine`` lower-case, ``line``, ``start`` offset), its instruction
    ``name``, ``motion`` (``L``: ``ConfL`` governs it, ``J``: ``ConfJ``, ``""``: neither),
    its target references (``("decl", (Decl, index text or None))`` or ``("inline",
    Node)``), tool and work object names, and the monitoring state ``conf`` in force
    (set by :func:`monitoring`)."""

    module: Module
    routine: str
    line: int
    start: int
    name: str
    motion: str
    refs: list[tuple[str, Any]] = field(default_factory=list)
    tool: str = ""
    work: str = "wobj0"
    conf: str = ON


def _positional(mod: Module, start: int, end: int) -> tuple[list[tuple[str, int]], str]:
    """A move's positional arguments (text, offset) and its ``\\WObj`` name."""
    code = mod.code
    simple = _SIMPLE_MOVE.fullmatch(code, start, end)
    if simple is not None:  # "p, speed, zone, tool[\WObj:=w]": no splitting needed
        return [(simple.group(g), simple.start(g)) for g in range(1, 5)], simple.group(5) or ""
    args: list[tuple[str, int]] = []
    work = ""
    for a, b in split_args(code, start, end):
        (pa, pb), opts = split_options(code, a, b)
        for opt in opts:
            key, _, val = opt.partition(":=")
            if key.strip().lower() == "wobj":
                work = val.strip()
        raw = code[pa:pb]
        arg = raw.strip()
        if arg:
            args.append((arg, pa + raw.find(arg[0])))
    return args, work


def read_moves(mod: Module, modules: list[Module]) -> list[Move]:
    """Every move of ``mod`` with its references resolved (see the module docstring).

    Raises
    ------
    FilterInputError
        A move not ended by ``;`` within its routine.
    """
    src, code = mod.source, mod.code
    out: list[Move] = []
    for m in MOVE.finditer(code):
        routine = mod.routine_at(m.start())
        if routine is None or m.group(1).lower() in ROBOT_STILL:
            continue  # a name in a declaration, or a move of the external axes only
        end = statement_end(code, m.end())
        line = src.line_of(m.start())
        if end >= routine.end:
            raise FilterInputError(src.name, f"{m.group(1)} is not ended by ';'", line)
        name = m.group(1)
        motion = _MOTION.match(name)
        kind = "" if motion is None or name.lower() == "moveabsj" else motion.group(1).upper()
        scope = routine.name.lower()
        args, work = _positional(mod, m.end(), end)
        mv = Move(mod, scope, line, m.start(), name, "L" if kind == "C" else kind)
        mv.work = work or "wobj0"
        at = TOOL_ARGUMENT.get(name.lower())
        if at is None:  # an instruction of unknown layout: a tooldata, else the last name
            tools = [
                k
                for k, (a, _) in enumerate(args)
                if a.lower() in PREDEFINED_TOOLS
                or lookup(a, scope, mod, modules, ("tooldata",))[0] is not None
            ]
            at = tools[0] if tools else len(args) - 1
        if 0 <= at < len(args) and _NAME.fullmatch(args[at][0]):
            mv.tool = args[at][0]
        known = TARGET_ARGUMENTS.get(name.lower(), (0,) if name.lower() in TOOL_ARGUMENT else None)
        for k, (arg, astart) in enumerate(args):
            if k == at or (known is not None and k not in known):
                continue
            wrap = _WRAP.match(arg)
            if wrap:
                a, b = split_args(code, astart + wrap.end(), astart + len(arg) - 1)[0]
                inner = code[a:b]
                arg, astart = inner.strip(), a + len(inner) - len(inner.lstrip())
            if arg.startswith("["):
                node = parse_literal(code, astart, src)
                if is_robtarget(node) or is_jointtarget(node):
                    mv.refs.append(("inline", node))
                elif known is not None:
                    raise FilterInputError(
                        src.name,
                        "inline value is neither a robtarget nor a jointtarget "
                        f"({name} argument {k + 1})",
                        src.line_of(node.start),
                    )
                continue  # a literal of another type (speeddata, zonedata …)
            r = _REF.match(arg)
            if r:
                decl, _ = lookup(r.group(1), scope, mod, modules, ("robtarget", "jointtarget"))
                if decl is not None:
                    mv.refs.append(("decl", (decl, r.group(2))))
        out.append(mv)
    return out


def _join(states: set[tuple[str, str]]) -> tuple[str, str]:
    ls, js = {s[0] for s in states}, {s[1] for s in states}
    return (ls.pop() if len(ls) == 1 else UNKNOWN, js.pop() if len(js) == 1 else UNKNOWN)


def monitoring(modules: list[Module], moves: list[Move]) -> dict[str, Move]:
    """Set every move's ``conf`` (see the module docstring); returns, for each routine
    called from exactly one place, the last move before that call (in its caller, or
    before the caller's own single call): where the robot comes from into the routine."""
    routines = {r.name.lower() for mod in modules for r in mod.routines}
    events: dict[str, list[tuple[int, str, Any]]] = defaultdict(list)
    any_off = False
    called: set[str] = set()
    for mod in modules:
        for m in _CONF.finditer(mod.code):
            r = mod.routine_at(m.start())
            if r is not None:
                off = m.group(2).lower() == "off"
                any_off |= off
                events[r.name.lower()].append((m.start(), "conf", (m.group(1).upper(), off)))
        for m in _CALL.finditer(mod.code):
            word = m.group(1).lower()
            r = mod.routine_at(m.start())
            if word in routines and r is not None:
                called.add(word)
                events[r.name.lower()].append((m.start(), "call", word))
    for mv in moves:
        events[mv.routine].append((mv.start, "move", mv))
    default = (UNKNOWN, UNKNOWN) if any_off else (ON, ON)
    entry: dict[str, tuple[str, str]] = {}

    def walk(routine: str, state: tuple[str, str], incoming: Any) -> None:
        conf_l, conf_j = state
        for _, kind, data in sorted(events[routine], key=lambda e: e[0]):
            if kind == "conf":
                axis, off = data
                if axis == "L":
                    conf_l = OFF if off else ON
                else:
                    conf_j = OFF if off else ON
            elif kind == "call":
                if incoming is not None:
                    incoming[data].add((conf_l, conf_j))
            elif incoming is None:
                mv: Move = data
                mv.conf = {"L": conf_l, "J": conf_j}.get(mv.motion, ON)

    def start(routine: str) -> tuple[str, str] | None:
        if routine == "main":
            return (ON, ON)
        return entry.get(routine) if routine in called else default

    for _ in range(len(routines) + 2):
        incoming: dict[str, set[tuple[str, str]]] = defaultdict(set)
        for routine in routines:
            state = start(routine)
            if state is not None:
                walk(routine, state, incoming)
        new = {r: _join(s) for r, s in incoming.items() if s}
        if new == entry:
            break
        entry = new
    for routine in routines:
        walk(routine, start(routine) or (UNKNOWN, UNKNOWN), None)
    return _entries(events)


def _entries(events: dict[str, list[tuple[int, str, Any]]]) -> dict[str, Move]:
    sites: dict[str, list[tuple[str, int]]] = defaultdict(list)
    for caller, evs in events.items():
        for offset, kind, data in evs:
            if kind == "call":
                sites[data].append((caller, offset))
    out: dict[str, Move] = {}
    for routine in sites:
        seen = {routine}
        callee = routine
        while len(sites.get(callee, ())) == 1:
            caller, offset = sites[callee][0]
            before = [d for o, k, d in events[caller] if k == "move" and o < offset]
            if before:
                out[routine] = max(before, key=lambda mv: mv.start)
                break
            if caller in seen:
                break
            seen.add(caller)
            callee = caller
    return out
