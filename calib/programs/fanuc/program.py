"""Fanuc TP program as ASCII ``.LS``: ``/PROG``, ``/ATTR``, ``/MN``, ``/POS``, ``/END``.

Written::

    /PROG  CAL_PLAN
    /ATTR
    OWNER		= MNEDITOR;
    COMMENT		= "cablecal";
    ...
    DEFAULT_GROUP	= 1,*,*,*,*;
    CONTROL_CODE	= 00000000 00000000;
    /MN
       1:  ! cablecal: plan plan.csv ;
       ...
       4:J P[1] 25% FINE    ;
       5:  WAIT   2.00(sec) ;
       ...
    /POS
    P[1]{
       GP1:
        UF : 0, UT : 0,
        J1=     0.000 deg,    J2=   -30.000 deg,    J3=   200.000 deg,
        J4=     0.000 deg,    J5=    20.000 deg,    J6=     0.000 deg
    };
    /END

``J P[i] n% FINE`` is a joint move at ``speed_pct`` to an exact stop; ``WAIT x(sec)`` is the
dwell. Positions are in joint representation (``J1..J6`` in degrees, group 1, user frame 0,
tool frame 0), so no frame or configuration on the controller changes where the robot goes.
The header comment is three ``!`` remark lines in ``/MN`` (a remark holds 32 characters on
the pendant, so longer lines are wrapped). The name: an upper-case letter, then upper-case letters,
digits or ``_``, up to 36 characters (R-30iA and later; R-J3iB: 8), and the file is
``NAME.LS``. The controller compiles an ``.LS`` into a ``.TP`` when it is loaded (it needs the
ASCII Program Loader option, or convert it with ROBOGUIDE / ``maketp``).

The parser reads this subset back: the sections in order, ``/MN`` lines ``J P[i] n% FINE``,
``WAIT x(sec)`` and ``!`` remarks, ``/POS`` entries in joint representation of group 1. A
``CNT`` (blended) move, a Cartesian position or a position used but not defined is an error
naming the line.
"""

from __future__ import annotations

import re
import textwrap

from calib.programs.common import (
    JointProgram,
    Joints,
    NameRule,
    ProgramError,
)
from calib.programs.lexer import NUMBER_PATTERN, clean_comment

NAME_RULE = NameRule("Fanuc TP", 36, upper=True)
#: Characters of a ``!`` remark on the pendant.
REMARK_LEN = 32

_NUM = NUMBER_PATTERN


def _stamp(created_utc: str) -> str:
    """``YY-MM-DD  TIME hh:mm:ss`` of ``YYYY-MM-DD hh:mm:ss`` (the pendant's date format)."""
    m = re.fullmatch(r"\d\d(\d\d-\d\d-\d\d)[ T](\d\d:\d\d:\d\d)", created_utc.strip())
    return f"{m.group(1)}  TIME {m.group(2)}" if m else "00-01-01  TIME 00:00:00"


def write(program: JointProgram) -> str:
    """The ``.LS`` text of ``program``."""
    name = NAME_RULE.check(program.name)
    stamp = _stamp(program.created_utc)
    pct = max(1, min(100, round(program.speed_pct)))
    mn: list[str] = [
        f"! {part}"
        for c in program.comments
        for part in textwrap.wrap(clean_comment(c), REMARK_LEN - 2, break_on_hyphens=False)
    ]
    for i in range(1, len(program.joints_deg) + 1):
        mn.append(f"J P[{i}] {pct}% FINE    ")
        mn.append(f"WAIT {program.dwell_s:7.2f}(sec) ")
    lines = [
        f"/PROG  {name}",
        "/ATTR",
        "OWNER\t\t= MNEDITOR;",
        'COMMENT\t\t= "cablecal";',
        "PROG_SIZE\t= 0;",
        f"CREATE\t\t= DATE {stamp};",
        f"MODIFIED\t= DATE {stamp};",
        "FILE_NAME\t= ;",
        "VERSION\t\t= 0;",
        f"LINE_COUNT\t= {len(mn)};",
        "MEMORY_SIZE\t= 0;",
        "PROTECT\t\t= READ_WRITE;",
        "TCD:  STACK_SIZE\t= 0,",
        "      TASK_PRIORITY\t= 50,",
        "      TIME_SLICE\t= 0,",
        "      BUSY_LAMP_OFF\t= 0,",
        "      ABORT_REQUEST\t= 0,",
        "      PAUSE_REQUEST\t= 0;",
        "DEFAULT_GROUP\t= 1,*,*,*,*;",
        "CONTROL_CODE\t= 00000000 00000000;",
        "/MN",
    ]
    for k, text in enumerate(mn, start=1):
        if text.startswith("J "):
            lines.append(f"{k:4d}:{text};")
        else:
            lines.append(f"{k:4d}:  {text.rstrip()} ;")
    lines.append("/POS")
    for i, q in enumerate(program.joints_deg, start=1):
        v = [f"{x:9.3f}" for x in q]
        v = [s.replace("-0.000", " 0.000") if float(s) == 0 else s for s in v]
        lines += [
            f"P[{i}]{{",
            "   GP1:",
            "\tUF : 0, UT : 0,\t",
            f"\tJ1= {v[0]} deg,\tJ2= {v[1]} deg,\tJ3= {v[2]} deg,",
            f"\tJ4= {v[3]} deg,\tJ5= {v[4]} deg,\tJ6= {v[5]} deg",
            "};",
        ]
    lines += ["/END", ""]
    return "\n".join(lines)


def _positions(lines: list[tuple[int, str]]) -> dict[int, Joints]:
    """The ``/POS`` entries: position number → joints [deg]."""
    text = "\n".join(s for _, s in lines)
    first = lines[0][0] if lines else 0
    out: dict[int, Joints] = {}
    pos = 0
    for m in re.finditer(r"P\[(\d+)(?:\s*:\s*\"[^\"]*\")?\]\s*\{(.*?)\}\s*;", text, re.DOTALL):
        line = first + text.count("\n", 0, m.start())
        if text[pos : m.start()].strip():
            raise ProgramError(
                f"line {line}: unexpected text in /POS: {text[pos : m.start()].strip()[:40]!r}"
            )
        pos = m.end()
        body = m.group(2)
        if not re.search(r"GP1\s*:", body):
            raise ProgramError(f"line {line}: P[{m.group(1)}] has no GP1 group")
        body = body.split("GP2", 1)[0]
        if re.search(r"\b[XYZWPR]\s*=", body):
            raise ProgramError(f"line {line}: P[{m.group(1)}] is Cartesian; expected J1..J6")
        joints = dict(re.findall(r"\bJ([1-6])\s*=\s*(" + _NUM + r")\s*deg", body))
        if len(joints) != 6:
            raise ProgramError(f"line {line}: P[{m.group(1)}] needs J1..J6 in deg")
        q = [float(joints[str(j)]) for j in range(1, 7)]
        out[int(m.group(1))] = (q[0], q[1], q[2], q[3], q[4], q[5])
    if text[pos:].strip():
        raise ProgramError(f"line {first + text.count(chr(10), 0, pos)}: unexpected text in /POS")
    return out


def parse(text: str) -> JointProgram:
    """The program of an ``.LS`` file (the subset in the module docstring).

    Raises
    ------
    ProgramError
        Naming the line: sections missing or out of order, an unknown ``/MN`` instruction, a
        ``CNT`` move, an undefined or Cartesian position, no moves.
    """
    sections: dict[str, list[tuple[int, str]]] = {}
    name = ""
    current = ""
    order: list[str] = []
    for line_no, raw in enumerate(text.splitlines(), start=1):
        stmt = raw.strip()
        if not stmt:
            continue
        m = re.fullmatch(r"/(PROG|ATTR|APPL|MN|POS|END)\b\s*(.*)", stmt)
        if m:
            current = m.group(1)
            if current in order:
                raise ProgramError(f"line {line_no}: /{current} twice")
            order.append(current)
            sections[current] = []
            if current == "PROG":
                nm = re.fullmatch(r"([A-Za-z]\w*)(\s+Macro)?", m.group(2).strip())
                if not nm:
                    raise ProgramError(f"line {line_no}: /PROG needs a program name")
                name = nm.group(1)
            continue
        if not current:
            raise ProgramError(f"line {line_no}: expected /PROG, got {stmt!r}")
        if current == "END":
            raise ProgramError(f"line {line_no}: text after /END: {stmt!r}")
        sections[current].append((line_no, stmt))
    want = ["PROG", "MN", "POS", "END"]
    if [s for s in order if s in want] != want or order[0] != "PROG":
        raise ProgramError(f"sections: expected /PROG, /MN, /POS, /END in that order, got {order}")
    refs: list[tuple[int, int]] = []
    dwells: list[float] = []
    speeds: list[float] = []
    comments: list[str] = []
    for line_no, stmt in sections["MN"]:
        m = re.fullmatch(r"(\d+)?\s*:\s*(.*?)\s*;", stmt)
        if not m:
            raise ProgramError(f"line {line_no}: expected 'n: instruction ;', got {stmt!r}")
        body = m.group(2)
        if not body or body.startswith("!"):
            if body and not refs:
                comments.append(body[1:].strip())
            continue
        wm = re.fullmatch(r"WAIT\s+(" + _NUM + r")\s*\(sec\)", body)
        if wm:
            if not refs:
                raise ProgramError(f"line {line_no}: WAIT before the first move")
            dwells.append(float(wm.group(1)))
            continue
        jm = re.fullmatch(r"J\s+P\[(\d+)(?:\s*:\s*[^\]]*)?\]\s+(\d+)%\s+(FINE|CNT\s*\d+)(.*)", body)
        if not jm:
            raise ProgramError(f"line {line_no}: unknown instruction {body!r}")
        if jm.group(3) != "FINE":
            raise ProgramError(f"line {line_no}: {jm.group(3)} blends the move; expected FINE")
        if jm.group(4).strip():
            raise ProgramError(f"line {line_no}: unexpected motion option {jm.group(4).strip()!r}")
        refs.append((line_no, int(jm.group(1))))
        speeds.append(float(jm.group(2)))
    positions = _positions(sections["POS"])
    moves: list[Joints] = []
    for line_no, k in refs:
        if k not in positions:
            raise ProgramError(f"line {line_no}: P[{k}] is not defined in /POS")
        moves.append(positions[k])
    if not moves:
        raise ProgramError("/MN: no J move")
    return JointProgram(
        name=name,
        joints_deg=tuple(moves),
        speed_pct=min(max(min(speeds), 1.0), 100.0),
        dwell_s=min(dwells) if dwells else 0.0,
        comments=tuple(comments),
    )
