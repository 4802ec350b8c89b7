"""URScript dialect of the filter (``.script``, ``.urscript``), PolyScope exports included.

Targets
    Poses ``p[x, y, z, rx, ry, rz]`` (position in metres, rotation vector in radians) that
    a move uses: assigned to a name (``global Waypoint_1_p=p[…]``, ``home = p[…]``) or
    written inline (``movel(p[…], a=1.2, v=0.25)``). Joint lists ``[q1, …, q6]`` [rad] that
    ``movej`` uses, named or inline. A ``p[…]`` no move uses (a feature, ``set_tcp``'s
    argument, a payload's centre) is no target.

Moves
    ``movel``, ``movej``, ``movep``, ``movec`` (both poses), ``servoj``; the pose argument
    may be a name, a literal, ``get_inverse_kin(P, qnear=Q)`` (``Q`` a name or an inline
    list) or ``pose_trans(F, P)`` (``P``
    in the feature ``F``, a named ``p[…]``: ``F`` is the work object; the base frame
    otherwise).

Tool
    The last ``set_tcp(p[…])`` (or ``set_tcp(name)``) before the move in the text; without
    one, the flange (no TCP offset). A ``set_tcp`` whose argument is not a literal pose or a
    named one leaves the tool unresolved, and the targets moved with it are skipped.

Configuration (the branch)
    UR programs have no configuration field: the controller takes the IK solution nearest
    a joint reference: for ``get_inverse_kin(P, qnear=Q)`` and PolyScope's ``NAME_q``
    beside ``NAME_p``, that ``Q``; otherwise (``movel``, ``movep``, ``movej`` of a pose) the
    joints of the previous move in the text; the first pose with neither is left
    (:data:`NO_REFERENCE`). ``Q`` itself *follows* ``P``: it is moved by the correction of
    the pose's joints, so the pair stays consistent. The solutions are UR's closed form
    (:mod:`calib.filter.ur_ik`); a correction the controller would solve to another one
    from the same reference is left (:mod:`calib.filter.correct`).

Precision: positions to at least 6 decimals of a metre (rounding ≤ 0.0005 mm per axis),
rotation vectors and joints to at least 6 decimals of a radian (≤ 0.00003°); a number keeps
its own (often longer, PolyScope writes 12 or 16) decimals and its style (``.433`` stays
without the leading zero).
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from calib.kinematics import FloatArray
from calib.programs.formats import LANGUAGES
from calib.programs.lexer import NUMBER, URSCRIPT, close_bracket
from calib.programs.rotations import frame, matrix_to_rotvec, rotvec_to_matrix
from calib.programs.sites import (
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

NAME = "urscript"
EXTENSIONS = LANGUAGES[NAME].extensions
POSITION_DECIMALS = 6  # metres
#: The branch of a pose moved to first (no qnear, no move before it in the text).
NO_REFERENCE = "(none: no joint reference; the controller starts from the current joints)"
ANGLE_DECIMALS = 6  # radians

_ASSIGN = re.compile(
    r"^[ \t]*(?:global[ \t]+|local[ \t]+)?([A-Za-z_]\w*)[ \t]*=[ \t]*(p[ \t]*)?\[", re.MULTILINE
)
_MOVE = re.compile(r"(?<![\w.])(movel|movej|movep|movec|servoj)\s*\(")
_SET_TCP = re.compile(r"(?<![\w.])set_tcp\s*\(")
#: URScript's own marks: a ``def``/``thread``/``sec`` header with its colon, a motion or
#: script call, a ``p[…]`` literal, a ``global`` assignment.
_URSCRIPT = re.compile(
    r"^[ \t]*(?:def|thread|sec)[ \t]+\w+[ \t]*\([^)\n]*\)[ \t]*:"
    r"|(?<![\w.])(?:movel|movej|movep|movec|servoj|set_tcp|get_inverse_kin|textmsg|popup|sync)"
    r"[ \t]*\(|(?<![\w.])p[ \t]*\[|^[ \t]*global[ \t]+\w+[ \t]*=",
    re.MULTILINE,
)
#: Another controller's language: Fanuc LS sections, KRL headers and folds, RAPID modules.
_FOREIGN = re.compile(
    r"^[ \t]*(?:/PROG|/MN|/POS|/ATTR|&ACCESS|DEFDAT|DEF[ \t]+\w+[ \t]*\([^)\n]*\)[ \t]*$"
    r"|;FOLD|MODULE[ \t]|PROC[ \t])",
    re.MULTILINE,
)


#: ``text`` with ``#`` comments and string literals replaced by spaces (same length; the
#: shared lexer's, :mod:`calib.programs.lexer`).
blank = URSCRIPT.blank


def _numbers(code: str, src: Source, start: int, end: int) -> list[Num] | None:
    """The numbers of ``[a, b, …]`` spanning ``code[start:end]`` (brackets included), or
    None when an element is not a plain number."""
    out = []
    for a, b in split_args(code, start + 1, end - 1):
        item = code[a:b]
        s = item.strip()
        m = NUMBER.fullmatch(s)
        if not m:
            return None
        off = a + item.index(s)
        out.append(Num(src.name, off, off + len(s), src.text[off : off + len(s)], float(s)))
    return out


@dataclass(slots=True)
class PoseSite:
    """A ``p[…]``'s six numbers: x, y, z [m], rx, ry, rz [rad]."""

    numbers: list[Num]


@dataclass(slots=True)
class JointSite:
    """A joint list's six numbers [rad]."""

    numbers: list[Num]


def _pose_of(nums: list[Num]) -> FloatArray:
    v = np.array([n.value for n in nums])
    return frame(v[:3] * 1000.0, rotvec_to_matrix(v[3:]))


@dataclass
class _Value:
    kind: str  # "pose" or "joints"
    nums: list[Num]
    line: int
    name: str


@dataclass
class _File:
    src: Source
    code: str
    values: dict[str, _Value] = field(default_factory=dict)  # named p[...] and [...] lists


class URScriptDialect:
    """The URScript dialect (see the module docstring)."""

    name = NAME
    extensions = EXTENSIONS

    def claims(self, source: Source) -> bool:
        """Some URScript (:data:`_URSCRIPT`) and no other controller's language
        (:data:`_FOREIGN`: a Fanuc LS or KRL program named ``.script`` is refused)."""
        code = blank(source.text)
        return bool(_URSCRIPT.search(code)) and not _FOREIGN.search(code)

    def parse(self, sources: Sequence[Source], frames: FrameTables) -> list[Target]:
        del frames
        out: list[Target] = []
        for src in sources:
            out.extend(self._parse_one(src))
        return out

    def _value_at(self, f: _File, i: int, name: str) -> _Value | None:
        """A literal ``p[…]`` or ``[…]`` starting at ``i``."""
        code = f.code
        m = re.compile(r"(p\s*)?\[").match(code, i)
        if not m:
            return None
        start = m.end() - 1
        end = close_bracket(code, start)
        if end < 0:
            raise FilterInputError(f.src.name, "unclosed '['", f.src.line_of(start))
        nums = _numbers(code, f.src, start, end)
        if nums is None or len(nums) != 6:
            return None
        return _Value("pose" if m.group(1) else "joints", nums, f.src.line_of(start), name)

    def _parse_one(self, src: Source) -> list[Target]:
        f = _File(src, blank(src.text))
        code = f.code
        for m in _ASSIGN.finditer(code):
            v = self._value_at(f, m.end() - 1 - (len(m.group(2)) if m.group(2) else 0), m.group(1))
            if v is not None:
                f.values[m.group(1)] = v  # the last assignment in the text wins
        # Tools: set_tcp in text order.
        tcp_at: list[tuple[int, FloatArray | None, str]] = []
        for m in _SET_TCP.finditer(code):
            end = close_bracket(code, m.end() - 1)
            if end < 0:
                raise FilterInputError(src.name, "unclosed '(' of set_tcp", src.line_of(m.start()))
            arg = code[m.end() : end - 1].strip()
            off = m.end() + code[m.end() : end - 1].index(arg) if arg else m.end()
            v = self._value_at(f, off, "set_tcp")
            if v is None and arg in f.values and f.values[arg].kind == "pose":
                v = f.values[arg]
            line = src.line_of(m.start())
            if v is None or v.kind != "pose":
                tcp_at.append((m.start(), None, f"set_tcp at line {line}: not a literal pose"))
            else:
                tcp_at.append((m.start(), _pose_of(v.nums), f"set_tcp@{line}"))
        targets: dict[str, Target] = {}  # by key: the name, or "@offset" of an inline value
        order: list[Target] = []
        previous: str | None = None
        follows: dict[str, str] = {}  # joint-list name -> key of the pose it goes with

        def target_of(v: _Value, key: str, name: str) -> Target:
            if key in targets:
                return targets[key]
            if v.kind == "pose":
                t = Target(
                    src.name,
                    v.line,
                    name,
                    "cartesian",
                    pose=_pose_of(v.nums),
                    configuration=Configuration(text=NO_REFERENCE),
                    site=PoseSite(v.nums),
                )
            else:
                t = Target(
                    src.name,
                    v.line,
                    name,
                    "joint",
                    joints_deg=np.rad2deg([n.value for n in v.nums]),
                    site=JointSite(v.nums),
                )
            targets[key] = t
            order.append(t)
            return t

        for m in _MOVE.finditer(code):
            end = close_bracket(code, m.end() - 1)
            if end < 0:
                raise FilterInputError(
                    src.name, f"unclosed '(' of {m.group(1)}", src.line_of(m.start())
                )
            line = src.line_of(m.start())
            args = split_args(code, m.end(), end - 1)
            n_pose = 2 if m.group(1) == "movec" else 1
            tool: FloatArray | None = np.eye(4)
            tool_name, problem = "flange", ""
            before = [t for t in tcp_at if t[0] < m.start()]
            if before:
                _, tcp, label = before[-1]
                if tcp is None:
                    tool, tool_name, problem = None, "set_tcp", label
                else:
                    tool, tool_name = tcp, label
            for a, b in args[:n_pose]:
                got = self._move_arg(f, a, b)
                if got is None:
                    continue
                v, key, name, work, work_name, why, qnear = got
                t = target_of(v, key, name)
                cart = t.kind == "cartesian"
                reasons = "; ".join(w for w in (problem if cart else "", why) if w)
                t.uses.append(
                    Use(
                        src.name,
                        line,
                        tool_name,
                        work_name,
                        tool if cart else np.eye(4),
                        work,
                        reasons,
                    )
                )
                if qnear is not None:
                    follows[qnear] = key
                elif cart and previous is not None and len(t.uses) == 1:
                    t.configuration = Configuration(after=previous, text=f"nearest {previous}")
                previous = t.name
        # PolyScope pairs: Waypoint_n_q follows Waypoint_n_p.
        for name, v in f.values.items():
            if v.kind == "joints" and name.endswith("_q"):
                lead = name[:-2] + "_p"
                if lead in targets and targets[lead].kind == "cartesian":
                    follows.setdefault(name, lead)
        for qname, pkey in follows.items():
            v = f.values.get(qname)
            if v is None or v.kind != "joints":
                continue
            t = target_of(v, qname, v.name)
            lead_t = targets[pkey]
            t.follows = lead_t.name
            lead_t.configuration = Configuration(
                nearest_deg=np.asarray(t.joints_deg), text=f"nearest {t.name}"
            )
        return order

    def _move_arg(
        self, f: _File, a: int, b: int
    ) -> tuple[_Value, str, str, FloatArray | None, str, str, str | None] | None:
        """What an argument of a move names: the value, its key and name, the work object
        (frame, name, problem) and the ``qnear`` name; None when it names no target."""
        code = f.code
        s = code[a:b].strip()
        off = a + code[a:b].index(s) if s else a
        work: FloatArray | None = np.eye(4)
        work_name, why = "base", ""
        m = re.match(r"pose_trans\s*\(", s)
        if m:
            inner = split_args(code, off + m.end(), off + len(s) - 1)
            if len(inner) != 2:
                return None
            fa, fb = inner[0]
            feature = code[fa:fb].strip()
            fv = f.values.get(feature)
            work_name = feature
            if fv is None or fv.kind != "pose":
                work, why = None, f"feature {feature} is not a literal pose in this file"
            else:
                work = _pose_of(fv.nums)
            pa, pb = inner[1]
            s = code[pa:pb].strip()
            off = pa + code[pa:pb].index(s) if s else pa
        m = re.match(r"get_inverse_kin\s*\(", s)
        qnear = None
        if m:
            inner = split_args(code, off + m.end(), off + len(s) - 1)
            for ia, ib in inner[1:]:
                kw = code[ia:ib].strip()
                if kw.startswith("qnear") and "=" in kw:
                    qnear = kw.split("=", 1)[1].strip()
                    if qnear.startswith("["):  # an inline joint list: a target of its own
                        qoff = code.index("[", ia)
                        qv = self._value_at(f, qoff, "")
                        qnear = None
                        if qv is not None and qv.kind == "joints":
                            qv.name = f"qnear@{qv.line}"
                            qnear = f"@q{qoff}"
                            f.values[qnear] = qv
            pa, pb = inner[0]
            s = code[pa:pb].strip()
            off = pa + code[pa:pb].index(s) if s else pa
        if qnear is not None and qnear not in f.values:
            qnear = None
        if s.startswith("[") or re.match(r"p\s*\[", s):
            v = self._value_at(f, off, "")
            if v is None:
                return None
            return v, f"@{off}", f"inline@{v.line}", work, work_name, why, qnear
        if re.fullmatch(r"[A-Za-z_]\w*", s) and s in f.values:
            return f.values[s], s, s, work, work_name, why, qnear
        return None

    def render(self, target: Target, correction: Correction) -> list[Edit]:
        if isinstance(target.site, JointSite):
            assert correction.joints_deg is not None
            return edits_for(target.site.numbers, np.deg2rad(correction.joints_deg), ANGLE_DECIMALS)
        site: PoseSite = target.site
        assert correction.pose is not None
        old = np.array([n.value for n in site.numbers])
        rv = matrix_to_rotvec(correction.pose[:3, :3], near=old[3:])
        return [
            *edits_for(site.numbers[:3], correction.pose[:3, 3] / 1000.0, POSITION_DECIMALS),
            *edits_for(site.numbers[3:], rv, ANGLE_DECIMALS),
        ]


DIALECT = URScriptDialect()
