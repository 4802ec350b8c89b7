"""Fanuc ASCII TP dialect of the filter (``.ls``).

Targets
    Every ``P[n]`` (also ``P[n:"comment"]``) of the ``/POS`` section, group ``GP1`` only:
    Cartesian (``X, Y, Z`` [mm], ``W, P, R`` [deg] with ``R = Rz(R)·Ry(P)·Rx(W)``, and
    ``CONFIG``) or joint form (``J1 … J6`` [deg], Fanuc's own angles: J3 is the forearm's
    angle from the horizontal; the model's ``[controller]`` table says so). ``GP2`` and the
    other groups (a servo gun, a positioner, a rail) are never touched; a ``GP1`` with
    extended axes ``E1 …`` (an integrated rail moves the robot's base), a ``GP1`` in another
    representation (``RX … RR``) and a position that a ``/MN`` move reaches with ``INC`` (an
    increment) or an offset (``Offset``, ``Tool_Offset``, ``VOFFSET``) are left unchanged and
    named: the robot does not go to the position itself. A position register ``PR[n]`` that a
    move goes to lives on the controller, not in the program: named, never touched; so is an
    indirect one, ``PR[R[n]]`` (the register a data register names at run time).

Frames
    A position carries its own user frame and tool numbers (``UF : n, UT : m``; the
    controller refuses to run it under other numbers), resolved from ``--frames``
    (``[uframe.n]``, ``[utool.n]``; 0 is the identity). A number not given there leaves the
    position unchanged and named.

Configuration ``'F U T, t1, t4, t6'``
    The rules are :mod:`calib.programs.fanuc.config` (flip ``F`` when J5 > 0; the turn numbers
    of J1, J4, J6). The string is written back as it was: a correction that would change the
    flip or a turn number is refused (:meth:`FanucLsDialect.check`).

Precision: the file's own decimals, at least 3 for positions and ``W, P, R`` (what the
controller shows) and 4 for joint angles (it keeps a 32-bit REAL: about 7 significant digits).
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from calib.kinematics import N_JOINTS, FloatArray
from calib.programs.fanuc.config import KEYWORDS, TURN_JOINTS, configuration, refusal
from calib.programs.formats import LANGUAGES
from calib.programs.lexer import FANUC, NUMBER_PATTERN
from calib.programs.rotations import frames as make_frames
from calib.programs.rotations import matrix_to_zyx_deg, rotation_angle_deg, zyx_deg_to_matrix
from calib.programs.sites import (
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

NAME = "fanuc-ls"
EXTENSIONS = LANGUAGES[NAME].extensions
DECIMALS = 3
#: Joint angles to at least 4 decimals: a third decimal alone costs up to 0.0005 deg a joint,
#: about 0.02 mm at 2 m reach.
JOINT_DECIMALS = 4
#: Rotations closer than this are the same [deg]; W, P, R within this of P = ±90 [deg] are
#: at the Euler angles' lock.
_SAME_DEG = 1e-7
_LOCK_DEG = 0.01
#: Why a position register named in a move is left.
REGISTER_REASON = (
    "a position register: its value is on the controller (POSREG.VA), not in this program"
)
#: A move to the position register whose number a data register holds (``PR[R[86]]``).
INDIRECT_REGISTER_REASON = (
    "an indirect position register: the register is chosen at run time by a data register, "
    "and its value is on the controller (POSREG.VA), not in this program"
)

_NUM = NUMBER_PATTERN
_PROG = re.compile(r"^\ufeff?\s*/PROG\b")
_SECTION = re.compile(r"^[ \t]*/(PROG|ATTR|APPL|APPL_DATA|MN|POS|END)\b", re.MULTILINE)
_ENTRY = re.compile(r"P\[\s*(\d+)\s*(?::\s*\"[^\"\r\n]*\"\s*)?\]\s*\{")
_MN_LINE = re.compile(r"^[^\r\n]*", re.MULTILINE)
_MODIFIER = re.compile(r"\b(INC|Offset|Tool_Offset|VOFFSET)\b", re.IGNORECASE)
#: A /MN line that is a remark (``!``) or commented out (``//``): the lexicon's markers.
_REMARK = re.compile(r"\s*\d*\s*:\s*(?:" + "|".join(map(re.escape, FANUC.line_comments)) + ")")
_REF = re.compile(r"(?<![A-Za-z_])P\[\s*(\d+)")
_GROUP = re.compile(r"GP(\d+)\s*:")
_FIELD = re.compile(r"\b([A-Z]\w*)\s*=\s*(" + _NUM + r")\s*(mm|deg)?", re.IGNORECASE)
_FRAME_NO = re.compile(r"\b(UF|UT)\s*:\s*([^,\s]+)\s*,?")
_CONFIG = re.compile(r"\b(?:" + "|".join(KEYWORDS) + r")\s*:\s*'([^'\r\n]*)'")
_UNRECORDED = re.compile(r"=\s*\*{3,}")
#: A move to a position register: ``J PR[2] …``, ``L PR[3:Ablage] …``, or indirect,
#: ``J PR[R[86]] …``, ``L PR[R[71:curr_pr]] …`` (group 1 the number, group 2 the data register).
_REGISTER_MOVE = re.compile(
    r"^\s*\d*\s*:\s*[JLCA]\s+PR\[\s*(?:(\d+)|R\[\s*(\d+)\s*(?::[^\]\r\n]*)?\])",
    re.MULTILINE,
)
_CARTESIAN = ("X", "Y", "Z", "W", "P", "R")
_JOINTS = tuple(f"J{j}" for j in range(1, N_JOINTS + 1))


@dataclass(slots=True)
class CartSite:
    """Where a Cartesian position's numbers are: ``X, Y, Z``, ``W, P, R`` and the turns."""

    position: list[Num]
    wpr: list[Num]
    turns: list[Num]


@dataclass(slots=True)
class JointSite:
    joints: list[Num]


def _sections(src: Source) -> dict[str, tuple[int, int]]:
    """Section name → (start, end) offsets of its body."""
    marks = [(m.group(1).upper(), m.start(), m.end()) for m in _SECTION.finditer(src.text)]
    out: dict[str, tuple[int, int]] = {}
    for k, (name, _s, e) in enumerate(marks):
        if name in out:
            raise FilterInputError(src.name, f"/{name} twice", src.line_of(_s))
        out[name] = (e, marks[k + 1][1] if k + 1 < len(marks) else len(src.text))
    return out


def _modified(src: Source, start: int, end: int) -> dict[str, str]:
    """Positions that ``/MN`` moves to other than where they are: ``INC`` (an increment) or
    an offset (``Offset``, ``Tool_Offset``, ``VOFFSET``); name → why, the first such line."""
    out: dict[str, str] = {}
    for m in _MN_LINE.finditer(src.text, start, end):
        what = _MODIFIER.search(m.group())
        if not what or _REMARK.match(m.group()):
            continue
        why = (
            f"line {src.line_of(m.start())}: moved to with {what.group(1)}: the robot "
            "does not go to the position itself"
        )
        for ref in _REF.finditer(m.group()):
            out.setdefault(f"P[{ref.group(1)}]", why)
    return out


def _closing(text: str, i: int, src: Source) -> int:
    """Offset of the ``}`` closing the entry whose ``{`` precedes ``i``."""
    j = text.find("}", i)
    k = text.find("{", i)
    if j < 0 or (0 <= k < j):
        raise FilterInputError(
            src.name, "a position entry without its closing '};'", src.line_of(i)
        )
    return j


class FanucLsDialect:
    """The Fanuc LS dialect (see the module docstring)."""

    name = NAME
    extensions = EXTENSIONS

    def claims(self, source: Source) -> bool:
        """An ``.ls`` whose first line is ``/PROG``."""
        return bool(_PROG.match(source.text))

    def parse(self, sources: Sequence[Source], frames: FrameTables) -> list[Target]:
        out: list[Target] = []
        for src in sources:
            if not self.claims(src):
                raise FilterInputError(src.name, "not a Fanuc LS program (no /PROG line)", 1)
            sections = _sections(src)
            if "POS" not in sections:
                continue
            if "END" not in sections:
                raise FilterInputError(
                    src.name, "/POS without /END", src.line_of(sections["POS"][0])
                )
            positions = self._positions(src, *sections["POS"], frames)
            used = _modified(src, *sections.get("MN", (0, 0)))
            for t in positions:
                if not t.problem and t.name in used:
                    t.problem = used[t.name]
            out.extend(positions)
            out.extend(_registers(src, *sections.get("MN", (0, 0))))
        cart = [t for t in out if isinstance(t.site, CartSite)]
        if cart:  # every pose at once: R = Rz(R)·Ry(P)·Rx(W)
            xyz = np.array([[n.value for n in t.site.position] for t in cart])
            wpr = np.array([[n.value for n in t.site.wpr] for t in cart])
            poses = make_frames(xyz, zyx_deg_to_matrix(wpr[:, 2], wpr[:, 1], wpr[:, 0]))
            for t, pose in zip(cart, poses, strict=True):
                t.pose = pose
        return out

    def _positions(self, src: Source, start: int, end: int, frames: FrameTables) -> list[Target]:
        text = src.text
        out: list[Target] = []
        i = start
        while True:
            while i < end and text[i] in " \t\r\n":
                i += 1
            if i >= end:
                return out
            m = _ENTRY.match(text, i)
            if not m:
                raise FilterInputError(
                    src.name,
                    f"expected P[n]{{ in /POS, got {text[i : i + 20].splitlines()[0]!r}",
                    src.line_of(i),
                )
            close = _closing(text, m.end(), src)
            semi = re.compile(r"\s*;").match(text, close + 1)
            if not semi:
                raise FilterInputError(
                    src.name, "expected '};' after a position", src.line_of(close)
                )
            target = self._entry(src, f"P[{m.group(1)}]", m.start(), m.end(), close, frames)
            if target is not None:
                out.append(target)
            i = semi.end()

    def _entry(
        self, src: Source, name: str, at: int, start: int, end: int, frames: FrameTables
    ) -> Target | None:
        """The target of the entry ``P[n]{`` at offset ``at`` (body ``[start, end)``)."""
        text = src.text
        groups = list(_GROUP.finditer(text, start, end))
        gp1 = [g for g in groups if g.group(1) == "1"]
        if not gp1:
            return None  # positions of other groups only
        g = gp1[0]
        g_end = next((h.start() for h in groups if h.start() > g.start()), end)
        line = src.line_of(at)
        body = text[g.end() : g_end]
        fields: dict[str, Num] = {}
        units: dict[str, str] = {}
        for f in _FIELD.finditer(text, g.end(), g_end):
            key = f.group(1).upper()
            if key in fields:
                raise FilterInputError(src.name, f"{name}: {key} twice", src.line_of(f.start()))
            fields[key] = Num(src.name, f.start(2), f.end(2), f.group(2), float(f.group(2)))
            units[key] = (f.group(3) or "").lower()
        if all(k in fields for k in _JOINTS):
            joints = [fields[k] for k in _JOINTS]
            values = np.array([n.value for n in joints])
            t = Target(src.name, line, name, "joint", joints_deg=values, site=JointSite(joints))
            linear = [k for k in _JOINTS if units[k] != "deg"]
            extra = sorted(set(fields) - set(_JOINTS))
            if linear:
                t.problem = f"{', '.join(linear)} not in deg (a linear axis): not supported"
            elif extra:
                t.problem = f"GP1 has extended axes {', '.join(extra)}: not supported"
            return t
        missing = [k for k in _CARTESIAN if k not in fields]
        if missing and len(missing) < len(_CARTESIAN):
            raise FilterInputError(
                src.name,
                f"{name}: GP1 has neither J1..J6 nor X..R (missing {', '.join(missing)})",
                line,
            )
        if missing:  # never recorded (********), or another representation (RX .. RR)
            if _UNRECORDED.search(body):
                why = "never recorded (its values are ********): nothing to correct"
            else:
                why = f"GP1 holds {', '.join(fields)}: neither J1..J6 nor X..R, not supported"
            return Target(src.name, line, name, "cartesian", problem=why)
        numbers = {m.group(1): m.group(2) for m in _FRAME_NO.finditer(body)}
        cfg = _CONFIG.search(body)
        if not cfg or set(numbers) != {"UF", "UT"}:
            raise FilterInputError(
                src.name, f"{name}: a Cartesian GP1 needs UF, UT and CONFIG", line
            )
        if not all(re.fullmatch(r"\d+", v) for v in numbers.values()):
            raise FilterInputError(src.name, f"{name}: UF and UT must be numbers", line)
        turn_nums = self._turns(src, g.end() + cfg.start(1), cfg.group(1))
        try:
            conf = configuration(cfg.group(1), tuple(int(n.value) for n in turn_nums))
        except ValueError as exc:
            raise FilterInputError(src.name, f"{name}: {exc}", line) from None
        uf, ut = int(numbers["UF"]), int(numbers["UT"])
        work, tool = frames.get("uframe", uf), frames.get("utool", ut)
        missing_frames = [
            f"{label} {n} is not in --frames ([{table}.{n}])"
            for label, n, table, value in (("UF", uf, "uframe", work), ("UT", ut, "utool", tool))
            if value is None
        ]
        use = Use(src.name, line, f"UT:{ut}", f"UF:{uf}", tool, work, "; ".join(missing_frames))
        site = CartSite(
            [fields[k] for k in _CARTESIAN[:3]], [fields[k] for k in _CARTESIAN[3:]], turn_nums
        )
        t = Target(
            src.name,
            line,
            name,
            "cartesian",
            pose=np.eye(4),
            configuration=conf,
            uses=[use],
            site=site,
        )  # pose: see parse
        extra = sorted(set(fields) - set(_CARTESIAN))
        if extra:
            t.problem = f"GP1 has extended axes {', '.join(extra)}: not supported"
        for k in _CARTESIAN:
            want = "mm" if k in "XYZ" else "deg"
            if units[k] not in (want, ""):
                raise FilterInputError(
                    src.name, f"{name}: {k} in {units[k]}, expected {want}", line
                )
        return t

    @staticmethod
    def _turns(src: Source, at: int, text: str) -> list[Num]:
        """The turn numbers of a CONFIG string starting at offset ``at``."""
        out = []
        for m in re.finditer(r",\s*([-+]?\d+)\s*(?=,|$)", text):
            out.append(Num(src.name, at + m.start(1), at + m.end(1), m.group(1), float(m.group(1))))
        if len(out) > len(TURN_JOINTS):
            raise FilterInputError(
                src.name,
                f"CONFIG '{text}': more than {len(TURN_JOINTS)} turn numbers",
                src.line_of(at),
            )
        return out

    def render(self, target: Target, correction: Correction) -> list[Edit]:
        """The corrected numbers; none where :meth:`check` refuses (the CONFIG string is
        never rewritten)."""
        if self.check(target, correction):
            return []
        if isinstance(target.site, JointSite):
            assert correction.joints_deg is not None
            return edits_for(target.site.joints, correction.joints_deg.tolist(), JOINT_DECIMALS)
        site: CartSite = target.site
        assert correction.pose is not None and correction.joints_deg is not None
        wpr = _wpr_near(correction.pose[:3, :3], [n.value for n in site.wpr])
        edits = [
            *edits_for(site.position, correction.pose[:3, 3].tolist(), DECIMALS),
            *edits_for(site.wpr, wpr, DECIMALS),
        ]
        return edits

    def check(self, target: Target, correction: Correction) -> str:
        """Why a corrected target cannot be written: its CONFIG's flip or a turn number would
        change (:func:`calib.programs.fanuc.config.refusal`); empty when it can.

        ``correction.joints_deg`` are Fanuc's angles (the core's controller angles)."""
        if target.configuration is None or correction.joints_deg is None:
            return ""
        return refusal(target.configuration, correction.joints_deg)


def _wpr_near(rot: FloatArray, old_wpr: list[float]) -> list[float]:
    """``W, P, R`` [deg] of a rotation (3, 3), nearest the written ``old_wpr``.

    At ``P = ±90`` only ``R ∓ W`` is defined (a real backup writes ``W = -120.304, P =
    -90.000, R = 90.000``): the written ``R`` is kept there and ``W`` solved, when that gives
    the rotation to 1e-7 deg; the rotation the position already had keeps its numbers."""
    old = np.array(old_wpr)
    if rotation_angle_deg(zyx_deg_to_matrix(old[2], old[1], old[0]), rot) < _SAME_DEG:
        return [float(v) for v in old]
    r, p, w = matrix_to_zyx_deg(rot, near_deg=old[::-1]).tolist()
    if abs(abs(p) - 90.0) < _LOCK_DEG:
        sign = 1.0 if p > 0 else -1.0  # Rz(R) Ry(±90) Rx(W) depends on R ∓ W only
        w_kept = w + sign * (old[2] - r)
        w_kept += 360.0 * round((old[0] - w_kept) / 360.0)
        if rotation_angle_deg(zyx_deg_to_matrix(old[2], p, w_kept), rot) < _SAME_DEG:
            return [w_kept, p, float(old[2])]
    return [w, p, r]


def _registers(src: Source, start: int, end: int) -> list[Target]:
    """One target per position register a ``/MN`` move goes to (``J PR[2] …``), at its
    first use: named, never corrected (:data:`REGISTER_REASON`)."""
    out: dict[str, Target] = {}
    for m in _REGISTER_MOVE.finditer(src.text, start, end):
        direct = m.group(1) is not None
        name = f"PR[{m.group(1)}]" if direct else f"PR[R[{m.group(2)}]]"
        if name not in out:
            line = src.line_of(m.start(1 if direct else 2))
            why = REGISTER_REASON if direct else INDIRECT_REGISTER_REASON
            out[name] = Target(src.name, line, name, "cartesian", problem=why)
    return list(out.values())


DIALECT = FanucLsDialect()
