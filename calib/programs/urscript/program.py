"""Universal Robots URScript: ``def name(): … end`` with ``movej`` joint moves in radians.

Written::

    def cal_plan():
      # cablecal: plan plan.csv; robot hsr-jr680; 2026-11-25 10:00 UTC
      movej([0.00000000, -0.52359878, 3.49065850, 0.00000000, 0.34906585, 0.00000000],
            a=1.4, v=0.7854, r=0)   (one line in the file)
      sleep(2)
      ...
    end

``movej`` with blend radius ``r=0`` stops exactly at the target (a fine stop); ``v`` [rad/s] is
``speed_pct`` of :data:`MAX_JOINT_SPEED_RAD_S` (180 deg/s, the UR base joints' limit), ``a``
[rad/s²] UR's default joint acceleration :data:`JOINT_ACC_RAD_S2`. Joints are written in
radians to 8 decimals (1e-8 rad = 6e-7 deg), converted from the 0.001 deg values, so a
program read back gives the same 0.001 deg targets. The name: a letter, then letters, digits
or ``_``, up to 32 characters.

The parser reads this subset back: ``def name():``, ``#`` comments, ``movej([6 numbers], a=,
v=[, r=0])``, ``sleep(s)``, ``end``. A blended move (``r`` > 0) is refused (the sampler needs
the robot stopped); anything else is an error naming the line.
"""

from __future__ import annotations

import math
import re

from calib.programs.common import (
    DECIMALS,
    JointProgram,
    NameRule,
    ProgramError,
    fmt_num,
    round_joints,
)
from calib.programs.lexer import NUMBER_PATTERN, URSCRIPT, clean_comment
from calib.programs.parsing import Collected, parse_lines

NAME_RULE = NameRule("URScript", 32)
#: Joint speed at 100 % [rad/s] (180 deg/s).
MAX_JOINT_SPEED_RAD_S = math.pi
#: Joint acceleration of every move [rad/s²] (UR's movej default).
JOINT_ACC_RAD_S2 = 1.4
#: Decimals of a joint angle in radians.
RAD_DECIMALS = 8

_NUM = NUMBER_PATTERN


def write(program: JointProgram) -> str:
    """The URScript text of ``program``."""
    name = NAME_RULE.check(program.name)
    v = round(MAX_JOINT_SPEED_RAD_S * program.speed_pct / 100.0, 4)
    lines = [f"def {name}():"]
    lines += [f"  # {clean_comment(c)}" for c in program.comments]
    for q in round_joints(program.joints_deg):
        rad = ", ".join(f"{math.radians(d):.{RAD_DECIMALS}f}" for d in q)
        lines.append(f"  movej([{rad}], a={fmt_num(JOINT_ACC_RAD_S2)}, v={fmt_num(v, 4)}, r=0)")
        lines.append(f"  sleep({fmt_num(program.dwell_s)})")
    lines += ["end", ""]
    return "\n".join(lines)


def parse(text: str) -> JointProgram:
    """The program of a URScript function (the subset in the module docstring).

    Raises
    ------
    ProgramError
        Naming the line: no ``def name():``/``end``, an unknown statement, a blended or
        malformed ``movej``, no moves.
    """
    got = Collected()

    def outside(stmt: str, line_no: int) -> str:
        m = re.fullmatch(r"def\s+([A-Za-z_]\w*)\s*\(\s*\)\s*:", stmt)
        if not m:
            raise ProgramError(f"line {line_no}: expected def name():, got {stmt!r}")
        got.name = m.group(1)
        return "body"

    def body(stmt: str, line_no: int) -> str:
        if stmt == "end":
            return "done"
        m = re.fullmatch(r"sleep\(\s*(" + _NUM + r")\s*\)", stmt)
        if m:
            got.dwell(float(m.group(1)), line_no, "sleep", "movej")
            return "body"
        m = re.fullmatch(
            r"movej\(\s*\[([^\]]*)\]\s*((?:,\s*[avtr]\s*=\s*" + _NUM + r"\s*)*)\)", stmt
        )
        if not m:
            raise ProgramError(f"line {line_no}: unknown statement {stmt!r}")
        values = [v.strip() for v in m.group(1).split(",")]
        if len(values) != 6 or not all(re.fullmatch(_NUM, v) for v in values):
            raise ProgramError(f"line {line_no}: movej needs 6 joint angles in radians")
        kw = dict(re.findall(r"([avtr])\s*=\s*(" + _NUM + r")", m.group(2)))
        if float(kw.get("r", "0")) != 0:
            raise ProgramError(
                f"line {line_no}: a blended movej (r > 0) does not stop at the target"
            )
        if "v" in kw:
            got.speed_pct = round(float(kw["v"]) / MAX_JOINT_SPEED_RAD_S * 100.0, 2)
        q = [round(math.degrees(float(v)), DECIMALS) + 0.0 for v in values]
        got.moves.append((q[0], q[1], q[2], q[3], q[4], q[5]))
        return "body"

    # A '#' inside a statement is not a comment here: such a line is an unknown statement.
    parse_lines(
        text,
        got,
        lexicon=URSCRIPT,
        inline_comments=False,
        header_state="body",
        handlers={"outside": outside, "body": body},
        missing={"outside": "def name():", "body": "end"},
        end="end",
    )
    speed_pct = got.speed_pct if got.speed_pct is not None else 100.0
    return got.program(min(max(speed_pct, 1.0), 100.0), f"{got.name}: no movej")
