"""ABB RAPID: a program module with ``PROC main()`` of ``MoveAbsJ`` joint moves.

Written::

    MODULE CAL_PLAN
        ! cablecal: plan plan.csv; robot hsr-jr680; 2026-11-25 10:00 UTC
        CONST speeddata vCablecal:=[250,125,5000,1000];
        CONST jointtarget jt1:=[[0.000,-30.000,200.000,0.000,20.000,0.000],[9E+09,...]];
        ...
        PROC main()
            MoveAbsJ jt1\\NoEOffs, vCablecal, fine, tool0;
            WaitTime\\InPos, 2;
            ...
        ENDPROC
    ENDMODULE

The speed: :data:`V1000` scaled by ``speed_pct`` (``v_tcp`` and ``v_ori``; MoveAbsJ's joint
speed follows them); the external axes are ``9E+09`` (not connected). ``fine`` is the exact
stop; ``WaitTime\\InPos`` starts the dwell only once the robot is in position. Module and
routine names: a letter, then letters, digits or ``_``, up to 32 characters (RAPID's identifier
rule).

The parser reads this subset back (RAPID is case-insensitive; any indentation; ``!`` comments):
the module, ``CONST``/``PERS``/``VAR`` ``jointtarget`` and ``speeddata`` declarations, and in
``PROC main()`` ``MoveAbsJ`` to a declared jointtarget or an inline one, ``WaitTime`` and
``ConfL``/``ConfJ``. Anything else is an error naming the line.
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
from calib.programs.lexer import NUMBER_PATTERN, RAPID, clean_comment, number_value
from calib.programs.parsing import Collected, parse_lines

NAME_RULE = NameRule("RAPID", 32)
#: ABB's v1000: TCP 1000 mm/s, orientation 500 deg/s, external axes 5000 mm/s, 1000 deg/s.
V1000 = (1000.0, 500.0, 5000.0, 1000.0)
SPEED_NAME = "vCablecal"
#: External-axis value of a jointtarget for an axis that is not there.
NO_AXIS = "9E+09"

_NUM = NUMBER_PATTERN


def _number(text: str, line: int) -> float:
    """A number's value; ``ProgramError`` naming the line when it is absurdly long or not
    finite (``9E+999``)."""
    return number_value(
        text, lambda shown: ProgramError(f"line {line}: number {shown} is out of range")
    )


def write(program: JointProgram) -> str:
    """The RAPID module text of ``program`` (``\\n`` line ends)."""
    name = NAME_RULE.check(program.name)
    scale = program.speed_pct / 100.0
    speed = [V1000[0] * scale, V1000[1] * scale, V1000[2], V1000[3]]
    lines = [f"MODULE {name}"]
    lines += [f"    ! {clean_comment(c)}" for c in program.comments]
    lines.append(f"    CONST speeddata {SPEED_NAME}:=[{','.join(fmt_num(v) for v in speed)}];")
    ext = ",".join([NO_AXIS] * 6)
    for i, q in enumerate(program.joints_deg, start=1):
        lines.append(f"    CONST jointtarget jt{i}:=[[{','.join(fmt_deg(v) for v in q)}],[{ext}]];")
    lines.append("    PROC main()")
    for i in range(1, len(program.joints_deg) + 1):
        lines.append(f"        MoveAbsJ jt{i}\\NoEOffs, {SPEED_NAME}, fine, tool0;")
        lines.append(f"        WaitTime\\InPos, {fmt_num(program.dwell_s)};")
    lines += ["    ENDPROC", "ENDMODULE", ""]
    return "\n".join(lines)


def _jointtarget(text: str, line: int) -> Joints:
    m = re.fullmatch(r"\[\s*\[([^\]]*)\]\s*,\s*\[([^\]]*)\]\s*\]", text.strip())
    if not m:
        raise ProgramError(f"line {line}: not a jointtarget [[j1..j6],[e1..e6]]: {text.strip()!r}")
    robax = [v.strip() for v in m.group(1).split(",")]
    extax = [v.strip() for v in m.group(2).split(",")]
    if len(robax) != 6 or len(extax) != 6 or not all(re.fullmatch(_NUM, v) for v in robax + extax):
        raise ProgramError(f"line {line}: a jointtarget needs 6 robot and 6 external axis numbers")
    q = [_number(v, line) for v in robax]
    for v in extax:
        _number(v, line)
    return (q[0], q[1], q[2], q[3], q[4], q[5])


def parse(text: str) -> JointProgram:
    """The program of a RAPID module (the subset in the module docstring).

    Raises
    ------
    ProgramError
        Naming the line: no ``MODULE``/``PROC main()``, an unknown instruction, a MoveAbsJ to
        an undeclared target or without ``fine``, a malformed number, no moves.
    """
    got = Collected()
    targets: dict[str, Joints] = {}
    speeds: dict[str, float] = {}

    def outside(stmt: str, line_no: int) -> str:
        m = re.fullmatch(r"module\s+([A-Za-z]\w*)(\s*\([^)]*\))?", stmt, re.IGNORECASE)
        if not m:
            raise ProgramError(f"line {line_no}: expected MODULE name, got {stmt!r}")
        got.name = m.group(1)
        return "module"

    def module(stmt: str, line_no: int) -> str:
        if stmt.lower() == "endmodule":
            return "done"
        if re.fullmatch(r"proc\s+main\s*\(\s*\)", stmt, re.IGNORECASE):
            return "main"
        m = re.fullmatch(
            r"(?:const|pers|var)\s+(jointtarget|speeddata)\s+([A-Za-z]\w*)\s*:=\s*(.*);",
            stmt,
            re.IGNORECASE,
        )
        if not m:
            raise ProgramError(
                f"line {line_no}: expected a declaration or PROC main(), got {stmt!r}"
            )
        kind, var, value = m.group(1).lower(), m.group(2).lower(), m.group(3)
        if kind == "jointtarget":
            targets[var] = _jointtarget(value, line_no)
        else:
            sm = re.fullmatch(
                rf"\[\s*({_NUM})\s*,\s*{_NUM}\s*,\s*{_NUM}\s*,\s*{_NUM}\s*\]", value.strip()
            )
            if not sm:
                raise ProgramError(f"line {line_no}: speeddata needs 4 numbers, got {value!r}")
            speeds[var] = _number(sm.group(1), line_no)
        return "module"

    def main(stmt: str, line_no: int) -> str:
        if stmt.lower() == "endproc":
            return "module"
        if not stmt.endswith(";"):
            raise ProgramError(f"line {line_no}: missing ';' after {stmt!r}")
        body = stmt[:-1].strip()
        if re.fullmatch(r"conf[jl]\s*\\\s*(on|off)", body, re.IGNORECASE):
            return "main"
        m = re.fullmatch(r"waittime\s*(\\\s*inpos\s*)?,?\s*(" + _NUM + r")", body, re.IGNORECASE)
        if m:
            got.dwell(_number(m.group(2), line_no), line_no, "WaitTime", "MoveAbsJ")
            return "main"
        m = re.fullmatch(r"moveabsj\s+(.+)", body, re.IGNORECASE | re.DOTALL)
        if not m:
            raise ProgramError(f"line {line_no}: unknown instruction {body!r}")
        args = m.group(1)
        if args.lstrip().startswith("["):
            end = args.index("]]") + 2 if "]]" in args else -1
            if end < 0:
                raise ProgramError(f"line {line_no}: unterminated jointtarget")
            target, rest = _jointtarget(args[:end], line_no), args[end:]
        else:
            tm = re.match(r"\s*([A-Za-z]\w*)", args)
            if not tm or tm.group(1).lower() not in targets:
                raise ProgramError(
                    f"line {line_no}: MoveAbsJ to an undeclared jointtarget: {args!r}"
                )
            target, rest = targets[tm.group(1).lower()], args[tm.end() :]
        parts = [
            p.strip()
            for p in re.sub(r"^\s*(\\\s*NoEOffs)?", "", rest, flags=re.IGNORECASE).split(",")
        ]
        if len(parts) < 4 or parts[0] != "" or parts[2].lower() != "fine":
            raise ProgramError(
                f"line {line_no}: expected MoveAbsJ target, speed, fine, tool; got {body!r}"
            )
        speed = parts[1].lower()
        if speed not in speeds:
            raise ProgramError(f"line {line_no}: undeclared speeddata {parts[1]!r}")
        got.speed_pct = 100.0 * speeds[speed] / V1000[0]
        got.moves.append(target)
        return "main"

    # outside → module → main → module → done
    parse_lines(
        text,
        got,
        lexicon=RAPID,
        inline_comments=True,
        header_state="module",
        handlers={"outside": outside, "module": module, "main": main},
        missing={"outside": "MODULE", "module": "ENDMODULE", "main": "ENDPROC"},
        end="ENDMODULE",
    )
    return got.program(
        got.speed_pct if got.speed_pct is not None else 100.0, "PROC main(): no MoveAbsJ"
    )
