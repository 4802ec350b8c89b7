"""Fanuc ASCII TP dialect of the filter (``.ls``).

Targets
    Every ``P[n]`` (also ``P[n:"comment"]``) of the ``/POS`` section, group ``GP1`` only:
    Cartesian (``X, Y, Z`` [mm], ``W, P, R`` [deg] with ``R = Rz(R)·Ry(P)·Rx(W)``, and
    ``CONFIG``) or joint form (``J1 … J6`` [deg]). ``GP2`` and the other groups (a
    positioner, a rail) are never touched; a ``GP1`` with extended axes ``E1 …`` (an
    integrated rail moves the robot's base) is left unchanged and named, as is a position
    that a ``/MN`` move reaches with ``INC`` (an increment) or an offset (``Offset``,
    ``Tool_Offset``, ``VOFFSET``): the robot does not go to the position itself. Position
    registers ``PR[n]`` live on the controller, not in the program: never touched.

Frames
    A position carries its own user frame and tool numbers (``UF : n, UT : m``; the
    controller refuses to run it under other numbers), resolved from ``--frames``
    (``[uframe.n]``, ``[utool.n]``; 0 is the identity). A number not given there leaves the
    position unchanged and named.

Configuration ``'F U T, t4, t5, t6'``
    ``N``/``F``: wrist +1 (``J5 ≥ 0``) / −1; ``U``/``D``: elbow up / down; ``T``/``B``:
    wrist centre in front of / behind axis 1 (the branch signs of
    :class:`calib.filter.sites.Configuration`). The turn numbers are those of ``J4, J5, J6``:
    turn ``k`` is the window ``[−180 + 360k, 180 + 360k)`` [deg]. The letters are written
    back as they were, the turn numbers from the corrected joints.

Precision: the file's own decimals, at least 3 for positions and ``W, P, R`` (what the
controller shows) and 4 for joint angles (it keeps a 32-bit REAL: about 7 significant digits).
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from calib.filter.rotations import frames as make_frames
from calib.filter.rotations import matrix_to_zyx_deg, zyx_deg_to_matrix
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
)
from calib.kinematics import N_JOINTS

NAME = "fanuc-ls"
EXTENSIONS = (".ls",)
DECIMALS = 3
#: Joint angles to at least 4 decimals: a third decimal alone costs up to 0.0005 deg a joint,
#: about 0.02 mm at 2 m reach.
JOINT_DECIMALS = 4
#: Joints (0-based) the CONFIG's turn numbers belong to.
TURN_JOINTS = (3, 4, 5)

_NUM = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
_PROG = re.compile(r"^\ufeff?\s*/PROG\b")
_SECTION = re.compile(r"^[ \t]*/(PROG|ATTR|APPL|APPL_DATA|MN|POS|END)\b", re.MULTILINE)
_ENTRY = re.compile(r"P\[\s*(\d+)\s*(?::\s*\"[^\"\r\n]*\"\s*)?\]\s*\{")
_MN_LINE = re.compile(r"^[^\r\n]*", re.MULTILINE)
_MODIFIER = re.compile(r"\b(INC|Offset|Tool_Offset|VOFFSET)\b", re.IGNORECASE)
_REMARK = re.compile(r"\s*\d*\s*:\s*(?:!|//)")
_REF = re.compile(r"(?<![A-Za-z_])P\[\s*(\d+)")
_GROUP = re.compile(r"GP(\d+)\s*:")
_FIELD = re.compile(r"\b([A-Z]\w*)\s*=\s*(" + _NUM + r")\s*(mm|deg)?", re.IGNORECASE)
_FRAME_NO = re.compile(r"\b(UF|UT)\s*:\s*([^,\s]+)\s*,?")
_CONFIG = re.compile(r"\bCONFIG\s*:\s*'([^'\r\n]*)'")
_CARTESIAN = ("X", "Y", "Z", "W", "P", "R")
_JOINTS = tuple(f"J{j}" for j in range(1, N_JOINTS + 1))
_LETTERS = {
    "N": ("wrist", 1),
    "F": ("wrist", -1),
    "U": ("elbow", 1),
    "D": ("elbow", -1),
    "T": ("shoulder", 1),
    "B": ("shoulder", -1),
}


@dataclass
class CartSite:
    """Where a Cartesian position's numbers are: ``X, Y, Z``, ``W, P, R`` and the turns."""

    position: list[Num]
    wpr: list[Num]
    turns: list[Num]


@dataclass
class JointSite:
    joints: list[Num]


def turn_number(angle_deg: float) -> int:
    """The Fanuc turn number of a joint angle [deg]: ``k`` with the angle in
    ``[−180 + 360k, 180 + 360k)``."""
    return math.floor((angle_deg + 180.0) / 360.0)


@lru_cache(maxsize=1024)
def configuration(text: str, turns: tuple[float, ...]) -> Configuration:
    """The branch a Fanuc controller takes for a CONFIG string (see the module docstring).

    Raises
    ------
    ValueError
        An unknown or repeated letter.
    """
    letters = text.split(",")[0]
    signs: dict[str, int] = {}
    for ch in re.sub(r"\s+", "", letters).upper():
        if ch not in _LETTERS or _LETTERS[ch][0] in signs:
            raise ValueError(f"CONFIG '{text}': unexpected letter {ch!r}")
        signs[_LETTERS[ch][0]] = _LETTERS[ch][1]
    ranges = np.tile([-np.inf, np.inf], (N_JOINTS, 1))
    for j, k in zip(TURN_JOINTS, turns, strict=False):
        ranges[j] = (-180.0 + 360.0 * k, 180.0 + 360.0 * k)
    return Configuration(
        ranges,
        shoulder=signs.get("shoulder"),
        elbow=signs.get("elbow"),
        wrist=signs.get("wrist"),
        text=f"'{text}'",
    )


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
        if missing:
            raise FilterInputError(
                src.name,
                f"{name}: GP1 has neither J1..J6 nor X..R (missing {', '.join(missing)})",
                line,
            )
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
            conf = configuration(cfg.group(1), tuple(n.value for n in turn_nums))
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
        if isinstance(target.site, JointSite):
            assert correction.joints_deg is not None
            return edits_for(target.site.joints, correction.joints_deg.tolist(), JOINT_DECIMALS)
        site: CartSite = target.site
        assert correction.pose is not None and correction.joints_deg is not None
        old = [n.value for n in site.wpr][::-1]  # R, P, W
        rpw = matrix_to_zyx_deg(correction.pose[:3, :3], near_deg=old).tolist()
        edits = [
            *edits_for(site.position, correction.pose[:3, 3].tolist(), DECIMALS),
            *edits_for(site.wpr, rpw[::-1], DECIMALS),
        ]
        for num, j in zip(site.turns, TURN_JOINTS, strict=False):
            new = turn_number(float(correction.joints_deg[j]))
            if new != int(num.value):
                edits.append(Edit(num.file, num.start, num.end, str(new)))
        return edits


DIALECT = FanucLsDialect()
