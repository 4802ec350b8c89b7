"""A RAPID module of targets in the shapes real modules hold, for the filter's speed bench.

Real RobotStudio and OLP modules mix every shape of target in one module: one-line and
multi-line ``CONST``/``PERS``/``VAR`` robtargets (``LOCAL``, ``TASK PERS``), robtarget
arrays used by index, inline robtargets inside moves, ``MoveC`` with two targets, joint
targets for ``MoveAbsJ``, several tools and work objects (``wobj0`` among them), numbers
written with 0 to 6 decimals, comments, and many routines. :func:`rapid_shapes` writes such a
module (its own text, in those shapes; no real file copied) from planned joints, so every
target is reachable and the filter does its whole work on each.
"""

from __future__ import annotations

import numpy as np

from calib.kinematics import FloatArray
from calib.models import RobotModel
from calib.programs.rotations import matrix_to_quat_wxyz

#: Targets per routine.
PER_PROC = 400
#: Elements of each robtarget array.
ARRAY_LEN = 4
_EXT = "[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]"


def _pos(t: FloatArray, dec: int) -> str:
    return "[" + ",".join(f"{v:.{dec}f}" for v in t[:3, 3]) + "]"


def _rot(t: FloatArray, dec: int) -> str:
    return "[" + ",".join(f"{v:.{dec}f}" for v in matrix_to_quat_wxyz(t[:3, :3])) + "]"


def _tooldata(name: str, tool: FloatArray) -> str:
    return (
        f"PERS tooldata {name}:=[TRUE,[{_pos(tool, 3)},{_rot(tool, 7)}],"
        "[4.5,[0,0,95],[1,0,0,0],0,0,0]];"
    )


def rapid_shapes(
    nominal: RobotModel,
    q_plan: FloatArray,
    tools: list[FloatArray],
    work: FloatArray,
    confdata: list[tuple[int, int, int, int]],
    newline: str = "\r\n",
) -> str:
    """A module of ``len(q_plan)`` targets (q_plan (n, 6) [deg]; ``tools`` TCP frames (4, 4)
    [mm]; ``work`` the work object (4, 4) [mm]; ``confdata`` RAPID's per target), in the
    shapes of the module docstring, cycling through them."""
    from calib.filter.branches import flange_frames
    from calib.programs.rotations import invert

    n = len(q_plan)
    flanges = flange_frames(nominal, q_plan)
    tool_names = [f"tShape{k}" for k in range(len(tools))]
    decl: list[str] = [
        "%%%",
        "  VERSION:1",
        "  LANGUAGE:ENGLISH",
        "%%%",
        "",
        "MODULE SHAPES",
        "  ! Targets of every shape (written for cablecal's bench; EMULATED).",
    ]
    decl += ["  " + _tooldata(nm, t) for nm, t in zip(tool_names, tools, strict=True)]
    decl.append(
        f'  TASK PERS wobjdata wShape:=[FALSE,TRUE,"",[{_pos(work, 2)},{_rot(work, 7)}],'
        "[[0,0,0],[1,0,0,0]]];"
    )
    procs: list[list[str]] = []
    body: list[str] = []
    i = 0
    shape = 0
    while i < n:
        if len(body) >= PER_PROC or not procs:
            body = []
            procs.append(body)
        k = i % len(tools)
        tool, tname = tools[k], tool_names[k]
        on_base = shape % 5 == 4
        wobj, wname = (np.eye(4), "wobj0") if on_base else (work, "wShape")
        arg = f"{tname}\\WObj:={wname}"

        def target(
            j: int, dec: int = 3, qdec: int = 7, wobj: FloatArray = wobj, tool: FloatArray = tool
        ) -> str:
            tg = invert(wobj) @ flanges[j] @ tool
            cf = ",".join(str(c) for c in confdata[j])
            return f"[{_pos(tg, dec)},{_rot(tg, qdec)},[{cf}],{_EXT}]"

        kind = shape % 8
        shape += 1
        if kind == 0:  # one line, CONST
            decl.append(f"  CONST robtarget p{i}:={target(i)};")
            body.append(f"    MoveL p{i}, v1000, z10, {arg};")
            i += 1
        elif kind == 1:  # LOCAL PERS over several lines, 6 and 8 decimals
            t = target(i, 6, 8).replace("],[", "],\n      [")
            decl.append(f"  LOCAL PERS robtarget p{i}:={t};")
            body.append(f"    MoveJ p{i}, v2000, fine, {arg};  ! approach")
            i += 1
        elif kind == 2 and i + ARRAY_LEN <= n:  # an array used by index
            items = ",\n    ".join(target(i + m) for m in range(ARRAY_LEN))
            decl.append(f"  VAR robtarget path{i}{{{ARRAY_LEN}}}:=[\n    {items}];")
            body += [f"    MoveL path{i}{{{m + 1}}}, v500, z5, {arg};" for m in range(ARRAY_LEN)]
            i += ARRAY_LEN
        elif kind == 3:  # inline in the move
            body.append(f"    MoveL {target(i, 2)}, v300, z1, {arg};")
            i += 1
        elif kind == 4:  # TASK PERS, one decimal
            decl.append(f"  TASK PERS robtarget p{i}:={target(i, 1, 6)};")
            body.append(f"    MoveL p{i}, v800, z20, {arg};")
            i += 1
        elif kind == 5 and i + 2 <= n:  # MoveC: a circle point and an end point
            decl.append(f"  CONST robtarget c{i}:={target(i)};")
            decl.append(f"  CONST robtarget c{i + 1}:={target(i + 1)};")
            body.append(f"    MoveC c{i}, c{i + 1}, v200, z1, {arg};")
            i += 2
        elif kind == 6:  # a joint target, integers and decimals mixed
            q = q_plan[i]
            joints = ",".join(f"{v:.0f}" if m % 2 else f"{v:.4f}" for m, v in enumerate(q))
            decl.append(f"  CONST jointtarget j{i}:=[[{joints}],{_EXT}];")
            body.append(f"    MoveAbsJ j{i}\\NoEOffs, v1000, fine, {tname};")
            i += 1
        else:  # one line with spaces, 4 decimals
            t = target(i, 4).replace(",", ", ")
            decl.append(f"  CONST robtarget p{i} := {t};")
            body.append(f"    MoveL p{i}, v1500, z50, {arg};")
            i += 1
    lines = decl
    for k, b in enumerate(procs):
        lines += ["", f"  PROC path_{k}()", *b, "  ENDPROC"]
    lines += ["", "ENDMODULE", ""]
    return newline.join(lines)
