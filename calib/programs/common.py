"""What every program format shares: the joint-target type, the CSV reader, the checks.

Joint values are written to 0.001 deg (:data:`DECIMALS`); a controller reaches a commanded
joint position far better than the 0.5 deg the plan's pose matching allows, and 0.001 deg at
a 1 m reach is 0.017 mm, below the cable sensor's resolution.
"""

from __future__ import annotations

import csv
import io
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, field

from calib.csvtext import restore_cell
from calib.programs.lexer import clean_comment as clean_comment

#: Joints of the arm; programs carry exactly six.
N_JOINTS = 6
#: Decimals of a joint angle in a program [deg].
DECIMALS = 3
#: Most targets in one program (Fanuc numbers positions P[1..9999]; the others have no
#: smaller limit that matters here).
MAX_TARGETS = 9999
#: Joint columns of a joint-target CSV (any case).
JOINT_COLUMNS = tuple(f"q{j + 1}" for j in range(N_JOINTS))
#: Fastest and slowest allowed speed [% of the robot's maximum].
SPEED_PCT_RANGE = (1.0, 100.0)
#: Longest dwell [s] (a minute per pose is already a mistake somewhere).
MAX_DWELL_S = 600.0


class ProgramError(ValueError):
    """A bad target file, option or program text; the message names the row or line."""


Joints = tuple[float, float, float, float, float, float]


@dataclass(frozen=True)
class JointProgram:
    """A robot program of absolute joint moves, each to a fine stop followed by a dwell.

    Attributes
    ----------
    name : str
        Program name (each format checks its controller's rules).
    joints_deg : tuple of 6-tuples of float, shape (n, 6) [deg]
        Targets in visiting order, in the controller's joint angles.
    speed_pct : float
        Joint speed, percent of the robot's maximum (1..100).
    dwell_s : float
        Wait after each fine stop [s].
    comments : tuple of str
        Header comment lines (plan, robot, date), without comment markers.
    created_utc : str
        When the program was made, ``YYYY-MM-DD hh:mm:ss`` UTC, or empty (formats with a
        creation stamp, Fanuc's ``CREATE``, use it).
    """

    name: str
    joints_deg: tuple[Joints, ...]
    speed_pct: float
    dwell_s: float
    comments: tuple[str, ...] = field(default=())
    created_utc: str = ""

    def __post_init__(self) -> None:
        if not self.joints_deg:
            raise ProgramError("targets: a program needs at least one target")
        if len(self.joints_deg) > MAX_TARGETS:
            raise ProgramError(f"targets: {len(self.joints_deg)} targets, at most {MAX_TARGETS}")
        for i, q in enumerate(self.joints_deg):
            if len(q) != N_JOINTS or not all(math.isfinite(v) for v in q):
                raise ProgramError(f"target {i + 1}: expected 6 finite joint angles, got {q}")
        lo, hi = SPEED_PCT_RANGE
        if not lo <= self.speed_pct <= hi:
            raise ProgramError(f"speed_pct: must be within {lo:g}..{hi:g} %, got {self.speed_pct}")
        if not 0 <= self.dwell_s <= MAX_DWELL_S:
            raise ProgramError(f"dwell_s: must be within 0..{MAX_DWELL_S:g} s, got {self.dwell_s}")


def fmt_deg(value: float) -> str:
    """A joint angle to :data:`DECIMALS` decimals, never ``-0.000``."""
    text = f"{value:.{DECIMALS}f}"
    return text[1:] if text.startswith("-") and float(text) == 0 else text


def fmt_num(value: float, decimals: int = 2) -> str:
    """A time or speed: ``decimals`` decimals, trailing zeros dropped (``3``, ``0.5``)."""
    text = f"{value:.{decimals}f}"
    text = text.rstrip("0").rstrip(".") if "." in text else text
    return "0" if text in ("", "-0") else text


def round_joints(rows: Sequence[Sequence[float]]) -> tuple[Joints, ...]:
    """Targets rounded to :data:`DECIMALS` decimals, as they will be written."""
    out = []
    for q in rows:
        r = tuple(round(float(v), DECIMALS) + 0.0 for v in q)
        out.append((r[0], r[1], r[2], r[3], r[4], r[5]))
    return tuple(out)


def check_limits(
    joints_deg: Sequence[Sequence[float]],
    limits_deg: Sequence[Sequence[float]],
    rows: Sequence[int] | None = None,
) -> None:
    """Every joint within its limits, as written (rounded to 0.001 deg).

    Parameters
    ----------
    joints_deg : sequence of 6-sequences, shape (n, 6) [deg]
    limits_deg : sequence of (min, max), shape (6, 2) [deg]
    rows : sequence of int, length n, optional
        The file row of each target for the message (default 1..n).

    Raises
    ------
    ProgramError
        Naming the first offending row and joint, e.g. ``row 7, q3: 301.000 deg is outside
        the joint limits [60, 300] deg``.
    """
    for i, q in enumerate(round_joints(joints_deg)):
        for j, v in enumerate(q):
            lo, hi = limits_deg[j]
            if not lo <= v <= hi:
                row = rows[i] if rows is not None else i + 1
                raise ProgramError(
                    f"row {row}, q{j + 1}: {fmt_deg(v)} deg is outside the joint limits "
                    f"[{lo:g}, {hi:g}] deg"
                )


@dataclass(frozen=True)
class TargetRows:
    """Joint targets read from a CSV: ``joints_deg`` shape (n, 6) [deg] and the file row
    (line, header = 1) of each."""

    joints_deg: tuple[Joints, ...]
    rows: tuple[int, ...]


def read_targets_csv(text: str, source: str = "targets", anchor: str | None = None) -> TargetRows:
    """Joint targets of a CSV: a plan (``cablecal plan``: ``pose, q1..q6, anchor, …``) or
    corrected targets (``cablecal compensate``: ``index, q1_nominal.., q1..q6, …, flags``).

    The header names ``q1..q6`` [deg] (any case, any order); other columns are ignored except
    ``flags``: a target ``compensate`` flagged (no solution, outside the limits, a branch jump)
    is refused, since a program must not drive the robot there. A plan for several sensor
    anchors (an ``anchor`` column with more than one id) needs ``anchor``: the sensor is moved
    by hand between them, so each anchor gets a program of its own.

    Raises
    ------
    ProgramError
        Naming ``source``, the row (file line, header = 1) and the column: a missing or
        duplicated column, an empty, non-numeric or non-finite cell, a flagged target, no rows.
    """
    reader = csv.reader(io.StringIO(text))
    header = next(reader, None)
    if header is None or not any(c.strip() for c in header):
        raise ProgramError(f"{source}: empty file; expected a header with q1..q6")
    names = [c.strip().lower() for c in header]
    seen: set[str] = set()
    for name in names:
        if name in seen and name:
            raise ProgramError(f"{source}: row 1: column {name!r} appears twice")
        seen.add(name)
    missing = [c for c in JOINT_COLUMNS if c not in names]
    if missing:
        raise ProgramError(
            f"{source}: row 1: missing column(s) {', '.join(missing)}; the header has "
            f"{', '.join(names)}"
        )
    cols = [names.index(c) for c in JOINT_COLUMNS]
    flags_col = names.index("flags") if "flags" in names else None
    anchor_col = names.index("anchor") if "anchor" in names else None
    anchors_seen: dict[str, None] = {}
    joints: list[Joints] = []
    rows: list[int] = []
    for line_no, row in enumerate(reader, start=2):
        if not any(c.strip() for c in row):
            continue
        if anchor_col is not None:
            row_anchor = restore_cell(row[anchor_col].strip()) if anchor_col < len(row) else ""
            anchors_seen[row_anchor] = None
            if anchor is not None and row_anchor != anchor:
                continue
        if flags_col is not None and flags_col < len(row) and row[flags_col].strip():
            raise ProgramError(
                f"{source}: row {line_no}: the target is flagged "
                f"({row[flags_col].strip().replace(';', ', ')}); fix or remove it first"
            )
        values = []
        for name, idx in zip(JOINT_COLUMNS, cols, strict=True):
            cell = row[idx].strip() if idx < len(row) else ""
            if not cell:
                raise ProgramError(f"{source}: row {line_no}, column {name!r}: missing value")
            if "_" in cell:
                raise ProgramError(
                    f"{source}: row {line_no}, column {name!r}: not a number: {cell!r}"
                )
            try:
                v = float(cell)
            except ValueError:
                raise ProgramError(
                    f"{source}: row {line_no}, column {name!r}: not a number: {cell!r}"
                ) from None
            if not math.isfinite(v):
                raise ProgramError(
                    f"{source}: row {line_no}, column {name!r}: not finite: {cell!r}"
                )
            values.append(v)
        joints.append((values[0], values[1], values[2], values[3], values[4], values[5]))
        rows.append(line_no)
    if anchor is not None and anchor not in anchors_seen:
        known = ", ".join(anchors_seen) or "none (no anchor column)"
        raise ProgramError(f"anchor: {anchor!r} is not in {source}; its anchors: {known}")
    if anchor is None and len(anchors_seen) > 1:
        raise ProgramError(
            f"anchor: {source} plans poses at anchors {', '.join(anchors_seen)}; the sensor is "
            "moved between them by hand, so write one program per anchor (choose one)"
        )
    if not joints:
        raise ProgramError(f"{source}: no targets after the header")
    if len(joints) > MAX_TARGETS:
        raise ProgramError(f"{source}: {len(joints)} targets, at most {MAX_TARGETS} per program")
    return TargetRows(tuple(joints), tuple(rows))


@dataclass(frozen=True)
class NameRule:
    """A controller's rule for program names: first character a letter, then letters,
    digits and underscores, at most ``max_len`` characters; ``upper``: upper case only."""

    language: str
    max_len: int
    upper: bool = False

    def check(self, name: str) -> str:
        """``name`` if valid, else :class:`ProgramError` saying what is wrong."""
        pattern = r"[A-Z][A-Z0-9_]*" if self.upper else r"[A-Za-z][A-Za-z0-9_]*"
        if not re.fullmatch(pattern, name):
            case = "upper-case " if self.upper else ""
            raise ProgramError(
                f"name: {name!r} is not a valid {self.language} program name (a {case}letter, "
                f"then {case}letters, digits or _)"
            )
        if len(name) > self.max_len:
            raise ProgramError(
                f"name: {name!r} has {len(name)} characters; {self.language} allows {self.max_len}"
            )
        return name

    def from_text(self, text: str) -> str:
        """A valid name made from ``text`` (a file stem): other characters become ``_``, a
        leading digit gets a ``P`` before it, cut to the length limit."""
        name = re.sub(r"[^A-Za-z0-9_]", "_", text) or "cablecal"
        if not name[0].isalpha():
            name = "P" + name
        name = name.upper() if self.upper else name
        return name[: self.max_len]
