"""KUKA KRL: a ``.src`` module with ``DEF name( ) … END`` of ``PTP {A1 …}`` axis moves.

Written::

    &ACCESS RVP
    &REL 1
    DEF cal_plan( )
    ; cablecal: plan plan.csv; robot hsr-jr680; 2026-11-25 10:00 UTC
    BAS(#INITMOV,0)
    $VEL_AXIS[1]=25
    ...
    $ACC_AXIS[6]=25
    PTP {A1 0.000,A2 -30.000,A3 200.000,A4 0.000,A5 20.000,A6 0.000}
    WAIT SEC 2
    ...
    END

``PTP`` without ``C_PTP`` is an exact stop; ``WAIT SEC`` also stops the advance run, so the
dwell starts once the robot is in position. ``BAS(#INITMOV,0)`` is the usual initialisation
(tool, base, default speeds), after which ``$VEL_AXIS[i]`` and ``$ACC_AXIS[i]`` [% of each
axis' maximum] take ``speed_pct``. No ``.dat`` is needed: the targets are inline aggregates
and nothing is declared, so the ``.src`` runs alone. The name: a letter, then letters, digits
or ``_``, up to 24 characters (KRL's name length), and it must equal the file name
(``cal_plan.src``): the controller looks the ``DEF`` up by file name.

The parser reads this subset back (KRL is case-insensitive): ``&`` header lines, ``;``
comments, ``DEF name( )``, ``BAS(...)``, ``$VEL_AXIS[i]=``, ``$ACC_AXIS[i]=``, ``PTP {A1 …
A6 …}`` (``AXIS:``/``E6AXIS:`` allowed; ``E1..E6`` ignored), ``WAIT SEC``, ``END``. A
``C_PTP``/``C_DIS`` (approximated) move is refused; anything else is an error naming the line.
"""

from __future__ import annotations

import re

from calib.programs.common import (
    JointProgram,
    Joints,
    NameRule,
    ProgramError,
    fmt_deg,
    fmt_num,
)
from calib.programs.lexer import KRL, NUMBER_PATTERN, clean_comment
from calib.programs.parsing import Collected, parse_lines

NAME_RULE = NameRule("KRL", 24)

_NUM = NUMBER_PATTERN


def write(program: JointProgram) -> str:
    """The ``.src`` text of ``program``."""
    name = NAME_RULE.check(program.name)
    pct = fmt_num(program.speed_pct, 0) if program.speed_pct >= 1 else "1"
    lines = ["&ACCESS RVP", "&REL 1", f"DEF {name}( )"]
    lines += [f"; {clean_comment(c)}" for c in program.comments]
    lines.append("BAS(#INITMOV,0)")
    lines += [f"$VEL_AXIS[{j}]={pct}" for j in range(1, 7)]
    lines += [f"$ACC_AXIS[{j}]={pct}" for j in range(1, 7)]
    for q in program.joints_deg:
        axes = ",".join(f"A{j} {fmt_deg(v)}" for j, v in enumerate(q, start=1))
        lines.append(f"PTP {{{axes}}}")
        lines.append(f"WAIT SEC {fmt_num(program.dwell_s)}")
    lines += ["END", ""]
    return "\n".join(lines)


def _axes(body: str, line: int) -> Joints:
    body = re.sub(r"^\s*(E6AXIS|AXIS)\s*:", "", body, flags=re.IGNORECASE)
    values: dict[str, float] = {}
    for part in body.split(","):
        m = re.fullmatch(r"\s*([AE][1-6])\s+(" + _NUM + r")\s*", part, re.IGNORECASE)
        if not m:
            raise ProgramError(f"line {line}: not an axis value 'A1 0.0': {part.strip()!r}")
        key = m.group(1).upper()
        if key in values:
            raise ProgramError(f"line {line}: {key} given twice")
        values[key] = float(m.group(2))
    missing = [f"A{j}" for j in range(1, 7) if f"A{j}" not in values]
    if missing:
        raise ProgramError(f"line {line}: PTP without {', '.join(missing)} (give all six axes)")
    return (values["A1"], values["A2"], values["A3"], values["A4"], values["A5"], values["A6"])


def parse(text: str) -> JointProgram:
    """The program of a ``.src`` (the subset in the module docstring).

    Raises
    ------
    ProgramError
        Naming the line: no ``DEF``/``END``, an unknown statement, an approximated or partial
        ``PTP``, no moves.
    """
    got = Collected()
    vel: list[float] = []

    def outside(stmt: str, line_no: int) -> str:
        if stmt.startswith("&"):
            return "outside"
        m = re.fullmatch(r"(?:GLOBAL\s+)?DEF\s+([A-Za-z_]\w*)\s*\(\s*\)", stmt, re.IGNORECASE)
        if not m:
            raise ProgramError(f"line {line_no}: expected DEF name( ), got {stmt!r}")
        got.name = m.group(1)
        return "body"

    def body(stmt: str, line_no: int) -> str:
        if stmt.upper() == "END":
            return "done"
        if re.fullmatch(r"BAS\s*\(\s*#\w+\s*,\s*" + _NUM + r"\s*\)", stmt, re.IGNORECASE):
            return "body"
        m = re.fullmatch(
            r"\$(VEL|ACC)_AXIS\s*\[\s*[1-6]\s*\]\s*=\s*(" + _NUM + ")", stmt, re.IGNORECASE
        )
        if m:
            if m.group(1).upper() == "VEL":
                vel.append(float(m.group(2)))
            return "body"
        m = re.fullmatch(r"WAIT\s+SEC\s+(" + _NUM + ")", stmt, re.IGNORECASE)
        if m:
            got.dwell(float(m.group(1)), line_no, "WAIT SEC", "PTP")
            return "body"
        m = re.fullmatch(r"PTP\s*\{([^}]*)\}\s*(\S.*)?", stmt, re.IGNORECASE)
        if not m:
            raise ProgramError(f"line {line_no}: unknown statement {stmt!r}")
        if m.group(2):
            raise ProgramError(
                f"line {line_no}: {m.group(2).strip()} approximates the move; the robot "
                "must stop at each target"
            )
        got.moves.append(_axes(m.group(1), line_no))
        return "body"

    parse_lines(
        text,
        got,
        lexicon=KRL,
        inline_comments=True,
        header_state="body",
        handlers={"outside": outside, "body": body},
        missing={"outside": "DEF name( )", "body": "END"},
        end="END",
    )
    return got.program(min(vel) if vel else 100.0, f"{got.name}: no PTP")
