"""Write and read programs by format name, and build one from a joint-target CSV."""

from __future__ import annotations

import datetime as dt
import importlib
from collections.abc import Callable, Sequence
from types import ModuleType

from calib.programs.common import (
    JointProgram,
    NameRule,
    ProgramError,
    check_limits,
    read_targets_csv,
    round_joints,
)
from calib.programs.formats import LANGUAGES, PROGRAM_FORMATS, looks_like


def _module(fmt: str) -> ModuleType:
    """The writer of ``fmt`` (the languages' registry names it; imported on first use)."""
    if fmt not in LANGUAGES:
        raise ProgramError(f"format: {fmt!r} is not one of {', '.join(PROGRAM_FORMATS)}")
    return importlib.import_module(LANGUAGES[fmt].program_module)


def name_rule(fmt: str) -> NameRule:
    """The controller's program-name rule of ``fmt``."""
    rule: NameRule = _module(fmt).NAME_RULE
    return rule


def write_program(fmt: str, program: JointProgram) -> str:
    """The text of ``program`` in format ``fmt`` (one of :data:`PROGRAM_FORMATS`), ``\\n``
    line ends (:func:`program_from_csv` gives the language's own)."""
    writer: Callable[[JointProgram], str] = _module(fmt).write
    return writer(program)


def parse_program(fmt: str, text: str) -> JointProgram:
    """Read a program of format ``fmt`` back; :class:`ProgramError` naming the line."""
    parser: Callable[[str], JointProgram] = _module(fmt).parse
    return parser(text)


def detect_format(text: str) -> str:
    """The format of a program text, or ``"csv"``: the first language whose signature its
    start matches (:func:`calib.programs.formats.looks_like`, the registry's one rule of what
    each language's text looks like: ``MODULE`` for RAPID, ``def name():`` for URScript,
    ``&``/``DEF`` for KRL, ``/PROG`` with its sections for Fanuc)."""
    found = looks_like(text)
    return found[0][0] if found else "csv"


def program_from_csv(
    text: str,
    *,
    fmt: str,
    name: str,
    limits_deg: Sequence[Sequence[float]],
    speed_pct: float,
    dwell_s: float,
    comments: Sequence[str] = (),
    source: str = "targets",
    created_utc: str = "",
    anchor: str | None = None,
) -> tuple[JointProgram, str]:
    """A program of the joint targets in CSV ``text`` (a plan or compensated targets) and its text
    in ``fmt``, with the language's line ending (:data:`~calib.programs.formats.LANGUAGES`: Fanuc's
    CRLF), for the command line and the API alike. Everything is checked before anything is
    returned: the CSV (row and column; ``anchor`` picks one anchor's poses of a plan), the joints
    against ``limits_deg`` (shape (6, 2) [deg]; row and joint), the name against the controller's
    rule, the speed and the dwell.

    Raises
    ------
    ProgramError
    """
    rule = name_rule(fmt)
    targets = read_targets_csv(text, source, anchor)
    check_limits(targets.joints_deg, limits_deg, targets.rows)
    program = JointProgram(
        name=rule.check(name),
        joints_deg=round_joints(targets.joints_deg),
        speed_pct=speed_pct,
        dwell_s=dwell_s,
        comments=tuple(comments),
        created_utc=created_utc,
    )
    return program, LANGUAGES[fmt].with_newline(write_program(fmt, program))


def build_program(
    text: str,
    *,
    fmt: str,
    name: str,
    robot_name: str,
    limits_deg: Sequence[Sequence[float]],
    speed_pct: float,
    dwell_s: float,
    what: str,
    source: str,
    anchor: str | None = None,
    now: dt.datetime | None = None,
) -> tuple[JointProgram, str]:
    """A robot program of joint targets as cablecal writes it, for ``cablecal program`` and
    the API's downloads alike: :func:`program_from_csv` with the header comments (``cablecal
    <what>``, the robot and the anchor, when it was made, speed and dwell) and the creation
    time stamped in.

    Parameters
    ----------
    text : str
        Joint-target CSV with ``q1..q6`` [deg] (a plan or compensated targets).
    robot_name : str
        The robot model's name, for the header.
    limits_deg : sequence, shape (6, 2)
        Joint limits [deg].
    speed_pct : float
        Joint speed [% of the robot's maximum].
    dwell_s : float
        Wait at each target [s].
    what : str
        What the targets are (``plan 3 of campaign 1``, ``program of targets.csv``).
    source : str
        Where the CSV came from, for error messages.
    anchor : str or None
        A plan's anchor to keep (None: every row).
    now : datetime or None
        The creation time (UTC); default: now, to the second.

    Raises
    ------
    ProgramError
    """
    made = now if now is not None else dt.datetime.now(dt.UTC).replace(microsecond=0)
    comments = (
        f"cablecal {what}",
        f"robot {robot_name}" + (f", sensor at anchor {anchor}" if anchor else ""),
        f"made {made:%Y-%m-%d %H:%M} UTC",
        f"speed {speed_pct:g} %, dwell {dwell_s:g} s",
    )
    return program_from_csv(
        text,
        fmt=fmt,
        name=name,
        limits_deg=limits_deg,
        speed_pct=speed_pct,
        dwell_s=dwell_s,
        comments=comments,
        source=source,
        created_utc=f"{made:%Y-%m-%d %H:%M:%S}",
        anchor=anchor,
    )
