r"""ABB RAPID dialect of the filter (``.mod``, ``.modx``, ``.prg``, ``.sys``).

Modules, routines, declarations and their scope: :mod:`calib.programs.rapid.decls`; moves,
their tools and work objects, and ``ConfL``/``ConfJ`` along the flow:
:mod:`calib.programs.rapid.moves`.

Targets
    ``robtarget`` and ``jointtarget`` declarations with a literal value, one target per array
    element (named ``p{2}``, ``p{1,3}``; a routine's own data ``Path_10/p10``), and inline
    literals ``[[x,y,z],[q1,q2,q3,q4],[cf1,cf4,cf6,cfx],[eax_a..eax_f]]`` inside moves
    (``inline@<line>``). A robtarget's value: position [mm], quaternion ``w, x, y, z``,
    configuration, external axes (never written). A jointtarget: six robot axes [deg],
    external axes (never written). A declaration whose value is not a literal
    (``:= Offs(p1, …)``, a PERS without value) is no target site: it has no numbers.
    A robtarget with an external axis value (any ``eax`` other than ``9E9``: a track, a
    positioner) is left with that reason (:data:`calib.programs.sites.EXTERNAL_AXIS_REASON`):
    the model has no external axes. A model whose ``[controller]`` says
    ``external_axes = 0`` has them corrected: the controller ignores a value for an axis
    that is not connected (RAPID reference, extjoint), and the values stay as written.

Frames
    tooldata ``[robhold, [[x,y,z],[q1..q4]], load]``: the TCP in the flange frame.
    wobjdata ``[robhold, ufprog, ufmec, uframe, oframe]``: the work object is
    ``uframe · oframe``. A stationary tool (tooldata ``robhold`` FALSE, wobjdata ``robhold``
    TRUE) or a work object moved by a mechanical unit (``ufprog`` FALSE) is not supported:
    its targets are left and named. A tool or work object declared in none of the given
    files is named, with the advice to add the module that declares it.

Configuration (ABB confdata ``[cf1, cf4, cf6, cfx]``, "Technical reference manual – RAPID
Instructions, Functions and Data types", confdata)
    ``cf1, cf4, cf6``: the quadrants of axes 1, 4, 6, ``floor(q / 90°)`` (0 for 0..90°,
    -1 for -90..0°). ``cfx`` 0..7 for the serial six-axis arms (the manual's table): wrist
    centre in front of (0-3) or behind (4-7) axis 1; in front of (0, 1, 4, 5) or behind
    (2, 3, 6, 7) the lower arm; axis 5 positive (even) or negative (odd). "The lower arm"
    is the arm's own side, fixed to it: the same elbow bend is "in front" with the wrist on
    either side of axis 1 (:func:`cfx_of`; docs/compensation.md names the sources). Where
    the confdata is honoured (``ConfL\On``/``ConfJ\On``) a target is corrected only when
    its corrected axes 1, 4, 6 stay within :data:`QUADRANT_EDGE_DEG` of their written
    quadrants (else it is left: the correction would change the configuration), and the
    confdata text is never rewritten; under ``\Off`` the controller ignores confdata: the
    filter seeds each target from the previous one along the routine and leaves the
    confdata text as it is.
    The first target (where the robot comes from is not in the program) takes its confdata
    where that fits a solution, else the only solution within the joint limits, else is
    left saying so (:attr:`calib.programs.sites.Configuration.honoured`).

Precision: positions to at least 3 decimals (rounding ≤ 0.0005 mm per axis), quaternion
components to at least 6 (≤ 1e-4°), joint angles to at least 4 (≤ 0.00005°).
"""

from __future__ import annotations

import re
from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from calib.kinematics import FloatArray
from calib.programs.formats import LANGUAGES
from calib.programs.rapid.decls import HEADER, Module, index_text, lookup, read_module
from calib.programs.rapid.moves import (
    ON,
    PREDEFINED_TOOLS,
    PREDEFINED_WOBJS,
    UNKNOWN,
    Move,
    monitoring,
    read_moves,
)
from calib.programs.rapid.syntax import (
    Node,
    blank,
    is_pose,
    is_robtarget,
    number,
    nums,
    pose,
)
from calib.programs.rotations import (
    frame,
    matrix_to_quat_wxyz,
    quat_wxyz_to_matrix,
)
from calib.programs.sites import (
    EXTERNAL_AXIS_ADVICE,
    EXTERNAL_AXIS_REASON,
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

NAME = "rapid"
EXTENSIONS = LANGUAGES[NAME].extensions
POSITION_DECIMALS = 3
QUATERNION_DECIMALS = 6
JOINT_DECIMALS = 4
#: An external axis that is not there (RAPID writes 9E9 or 9E+09).
NO_AXIS = 9e9
_EAX = "abcdef"


@dataclass(slots=True)
class RobSite:
    """Where a robtarget's numbers are: position (3), quaternion (4), confdata (4); whether
    the controller honours the confdata (False under ``ConfL\\Off``/``ConfJ\\Off``)."""

    position: list[Num]
    quaternion: list[Num]
    conf: list[Num]
    honoured: bool = True


@dataclass(slots=True)
class JointSite:
    """Where a jointtarget's six robot axes are."""

    joints: list[Num]


_OPEN = np.tile([-np.inf, np.inf], (6, 1))

#: A joint within this of the 90° line bounding its written quadrant still keeps that
#: quadrant [deg]; further across, the correction changes the configuration and the target is
#: left with that reason (its confdata is never rewritten). A quadrant names which solution
#: the controller takes, not a hard window: ABB's RobotStudio API accepts a solution "within
#: +-1 for Cf1, Cf4 and Cf6" of the stored one as compliant (``ConfigurationMode.Compliant``),
#: and ``ConfL\On`` stops only when axis 4 or 6 would turn by more than 90°. A nominal
#: solution exactly on a line (axis 4 of a downward tool, an all-zero hand-taught wrist) comes
#: back a rounding below it after any correction, and a pure turn of the base moves axis 1 by
#: the turn (a calibration's is a few tenths of a degree): 1° keeps both, and stays far from
#: a real change of quadrant (90°). The one home of this tolerance: :func:`configuration`
#: reads confdata with it, the engine refuses outside it.
QUADRANT_EDGE_DEG = 1.0


def cfx_of(shoulder: int, elbow: int, wrist: int) -> int:
    """ABB's ``cfx`` (0..7) of branch signs (:class:`calib.programs.sites.Configuration`):
    wrist centre behind axis 1 adds 4, behind the lower arm adds 2, axis 5 negative adds 1.
    "Lower arm" is the arm's own side, so in the shared signs (``elbow`` is measured towards
    the wrist centre) it is ``elbow · shoulder``."""
    return (0 if shoulder > 0 else 4) + (0 if elbow * shoulder > 0 else 2) + (wrist < 0)


def configuration(conf: Sequence[float]) -> Configuration:
    """The branch an ABB controller takes for confdata ``[cf1, cf4, cf6, cfx]`` (integers);
    the inverse of :func:`cfx_of` and ``floor(q / 90°)``: each quadrant widened by
    :data:`QUADRANT_EDGE_DEG` on both sides."""
    ranges = _OPEN.copy()
    for j, cf in zip((0, 3, 5), conf[:3], strict=True):
        ranges[j] = (90.0 * cf - QUADRANT_EDGE_DEG, 90.0 * cf + 90.0 + QUADRANT_EDGE_DEG)
    cfx = int(conf[3])
    text = "[" + ",".join(f"{int(c)}" for c in conf) + "]"
    if not 0 <= cfx <= 7:
        return Configuration(ranges, text=text)
    shoulder = 1 if cfx < 4 else -1
    return Configuration(
        ranges,
        shoulder=shoulder,
        elbow=(1 if cfx % 4 < 2 else -1) * shoulder,
        wrist=1 if cfx % 2 == 0 else -1,
        text=text,
    )


def _robtarget(
    src: Source,
    name: str,
    line: int,
    pos: list[Num],
    quat: list[Num],
    conf: list[Num],
    eax: list[Num],
) -> Target:
    """A Cartesian target from its numbers (checked: a quaternion of nonzero norm, integer
    confdata); left with the reason when it is on an external axis."""
    try:
        rot = quat_wxyz_to_matrix(np.array([n.value for n in quat]))
    except ValueError:
        raise FilterInputError(src.name, f"{name}: quaternion of zero norm", line) from None
    values = [n.value for n in conf]
    if any(v != round(v) for v in values):
        raise FilterInputError(src.name, f"{name}: confdata must be integers", line)
    on_axis = [f"eax_{_EAX[k]} = {n.text}" for k, n in enumerate(eax) if n.value != NO_AXIS]
    problem = ""
    if on_axis:
        problem = f"{EXTERNAL_AXIS_REASON} ({', '.join(on_axis)}): {EXTERNAL_AXIS_ADVICE}"
    return Target(
        src.name,
        line,
        name,
        "cartesian",
        pose=frame(np.array([n.value for n in pos]), rot),
        configuration=configuration(values),
        problem=problem,
        site=RobSite(pos, quat, conf),
    )


class RapidDialect:
    """The RAPID dialect (see the module docstring)."""

    name = NAME
    extensions = EXTENSIONS

    def claims(self, source: Source) -> bool:
        """A RAPID extension and a ``MODULE`` statement as the first code."""
        head = source.text[:65536]  # the header: comments and %%% blocks come first
        return bool(HEADER.match(blank(head).lstrip("\ufeff")))

    def parse(self, sources: Sequence[Source], frames: FrameTables) -> list[Target]:
        del frames  # RAPID declares its frames in the program
        modules = [read_module(src) for src in sources]
        order: list[Target] = []
        for mod in modules:
            for decl in mod.decls.values():
                if decl.kind not in ("robtarget", "jointtarget"):
                    continue
                name = f"{decl.scope}/{decl.name}" if decl.scope else decl.name
                if decl.fast is not None:
                    decl.targets[()] = self._target_fast(mod.source, name, decl.fast)
                for index, node in decl.elements.items():
                    decl.targets[index] = self._target(
                        mod.source, f"{name}{index_text(index)}", decl.kind, node
                    )
                # The targets hold the numbers now: let go of the literal's node tree.
                decl.value, decl.elements, decl.fast = None, {}, None
                order.extend(decl.targets.values())
        moves = [mv for mod in modules for mv in read_moves(mod, modules)]
        entries = monitoring(modules, moves)
        order.extend(self._uses(moves, modules, entries))
        return order

    # -- targets -----------------------------------------------------------------------
    def _target_fast(self, src: Source, name: str, m: re.Match[str]) -> Target:
        """A robtarget from :data:`ROBTARGET`'s groups (1-3 position, 4-7 quaternion, 8-11
        configuration, 12-17 external axes)."""
        got = [
            Num(src.name, m.start(g), m.end(g), m.group(g), number(m.group(g), src, m.start(g)))
            for g in range(1, 18)
        ]
        line = src.line_of(m.start())
        return _robtarget(src, name, line, got[:3], got[3:7], got[7:11], got[11:])

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
        pos, quat, conf, eax = (nums(node.items[k], src) for k in range(4))
        return _robtarget(src, name, line, pos, quat, conf, eax)

    # -- frames ------------------------------------------------------------------------
    def _frame_of(
        self, name: str, kind: str, mod: Module, scope: str, modules: list[Module]
    ) -> tuple[FloatArray | None, str]:
        key = (scope, name.lower(), kind)
        if key not in mod.frames:
            mod.frames[key] = self._resolve_frame(name, kind, mod, scope, modules)
        return mod.frames[key]

    def _resolve_frame(
        self, name: str, kind: str, mod: Module, scope: str, modules: list[Module]
    ) -> tuple[FloatArray | None, str]:
        if kind == "tooldata" and name.lower() in PREDEFINED_TOOLS:
            return np.eye(4), ""
        if kind == "wobjdata" and name.lower() in PREDEFINED_WOBJS:
            return np.eye(4), ""
        decl, why = lookup(name, scope, mod, modules, (kind,))
        if decl is None:
            return None, why or (
                f"{kind} {name} is not declared in the given files: add the module that declares it"
            )
        node = decl.value
        if node is None or decl.dims:
            return None, f"{kind} {name} ({decl.where}) has no literal value"
        items = node.items or []
        if kind == "tooldata":
            if len(items) != 3 or not is_pose(items[1]):
                return None, f"tooldata {name} ({decl.where}) is not [robhold,tframe,load]"
            if items[0].word.upper() != "TRUE":
                return None, f"tooldata {name}: stationary tool (robhold FALSE) is not supported"
            return pose(items[1]), ""
        if len(items) != 5 or not (is_pose(items[3]) and is_pose(items[4])):
            return None, (
                f"wobjdata {name} ({decl.where}) is not [robhold,ufprog,ufmec,uframe,oframe]"
            )
        if items[0].word.upper() != "FALSE":
            return None, f"wobjdata {name}: robot-held work object (robhold TRUE): not supported"
        if items[1].word.upper() != "TRUE":
            return None, f"wobjdata {name}: moved by a unit (ufprog FALSE): not supported"
        return pose(items[3]) @ pose(items[4]), ""

    # -- moves -------------------------------------------------------------------------
    def _use(self, mv: Move, modules: list[Module]) -> Use:
        mod, scope = mv.module, mv.routine
        if mv.tool:
            tool, why_t = self._frame_of(mv.tool, "tooldata", mod, scope, modules)
        else:
            tool, why_t = None, f"{mv.name}: no tool argument found"
        work, why_w = self._frame_of(mv.work, "wobjdata", mod, scope, modules)
        problem = "; ".join(w for w in (why_t, why_w) if w)
        return Use(mod.source.name, mv.line, mv.tool or "?", mv.work, tool, work, problem)

    def _uses(
        self, moves: list[Move], modules: list[Module], entries: dict[str, Move]
    ) -> list[Target]:
        """Record every move's use of its targets and each Cartesian target's configuration
        rule (:func:`_follow`); returns the inline targets."""
        inline: list[Target] = []
        seen: dict[tuple[str, int], int] = defaultdict(int)
        got: dict[int, tuple[list[Target], bool]] = {}  # per move: its targets, chained
        for mv in moves:
            src = mv.module.source
            use = self._use(mv, modules)
            targets: list[Target] = []
            chain = True
            for kind, ref in mv.refs:
                if kind == "inline":
                    node: Node = ref
                    line = src.line_of(node.start)
                    seen[(src.name, line)] += 1
                    n = seen[(src.name, line)]
                    name = f"inline@{line}" + (f"#{n}" if n > 1 else "")
                    shape = "robtarget" if is_robtarget(node) else "jointtarget"
                    t = self._target(src, name, shape, node)
                    inline.append(t)
                    targets.append(t)
                    continue
                decl, index = ref
                keys: list[tuple[int, ...]] = list(decl.targets)
                if index is not None and decl.dims:
                    try:
                        keys = [tuple(int(v) for v in index.split(","))]
                    except ValueError:  # a variable index: the move may use every element
                        chain = False
                targets.extend(decl.targets[k] for k in keys if k in decl.targets)
            for t in targets:
                t.uses.append(use)
            got[id(mv)] = (targets, chain)
        flows: dict[int, list[tuple[str, Target | None, int]]] = defaultdict(list)
        last: dict[tuple[str, str], Target | None] = {}
        for mv in moves:
            targets, chain = got[id(mv)]
            key = (mv.module.source.name, mv.routine)
            if key in last:
                before = last[key]
            else:  # the routine's first move: where its one caller leaves the robot
                entry = entries.get(mv.routine)
                lead = got[id(entry)] if entry is not None else ([], False)
                before = lead[0][-1] if lead[0] and lead[1] else None
            for t in targets:
                flows[id(t)].append((mv.conf, before if chain else None, mv.line))
                before = t if chain else None
            if targets:
                last[key] = before
        for mod in modules:
            for decl in mod.decls.values():
                for t in decl.targets.values():
                    _follow(t, flows[id(t)])
        for t in inline:
            _follow(t, flows[id(t)])
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
        # The confdata text stays: under ConfL/ConfJ\Off the controller ignores it, and where
        # it is honoured the engine corrected the target only with every joint within
        # QUADRANT_EDGE_DEG of its written quadrant (:func:`configuration`).
        return edits


def _follow(t: Target, flow: list[tuple[str, Target | None, int]]) -> None:
    """Set a Cartesian target's configuration rule from the monitoring at its uses: any use
    with confdata honoured → its confdata; all ignoring it → nearest the previous target
    along the routine (the first target of a routine: its confdata)."""
    # A target on external axes is followed too: the model may say there are none
    # (calib.filter.run clears that reason then).
    if t.kind != "cartesian" or not flow:
        return
    if t.problem and not t.problem.startswith(EXTERNAL_AXIS_REASON):
        return
    states = {s for s, _, _ in flow}
    if ON in states:
        return
    if UNKNOWN in states:
        line = next(n for s, _, n in flow if s == UNKNOWN)
        t.problem = (
            f"line {line}: ConfL/ConfJ unknown here (its routine is called with monitoring "
            "on and off, or by no given module: add the module that calls it)"
        )
        return
    t.site.honoured = False
    _, before, _ = flow[0]
    assert t.configuration is not None
    if before is None or before is t or before.file != t.file:
        # The first move under \Off (or one after a target of another file, which the core
        # cannot follow): the controller takes the solution nearest where the robot is,
        # which the program does not say. Its confdata where it fits a solution, else the
        # only solution within the joint limits, else left with this text.
        t.configuration = replace(
            t.configuration,
            honoured=False,
            text=f"{t.configuration.text}, the first move under ConfL/ConfJ\\Off: the "
            "controller takes the solution nearest where the robot is, which the program does "
            "not say; start the routine with a MoveAbsJ or write this target's confdata",
        )
        return
    t.configuration = Configuration(
        after=before.name, text=f"nearest {before.name} (confdata {t.configuration.text} ignored)"
    )


DIALECT = RapidDialect()
