"""EMULATED offline-planned KRL and Fanuc LS programs for the filter's tests.

The targets come from :func:`filter_cells.planned_targets` (joints ``q_plan`` on the
nominal model); the status/turn and CONFIG fields are those of ``q_plan`` as
:mod:`calib.filter.krl` and :mod:`calib.filter.fanuc_ls` read them. The shapes follow what
KUKA's inline forms and Fanuc's ASCII export write: ``;FOLD`` blocks with ``FDAT_ACT``,
``DECL E6POS`` with ``S``/``T``, ``$config.dat`` with ``TOOL_DATA``/``BASE_DATA``; ``/POS``
entries with ``GP1`` (Cartesian or joint form) and ``GP2``.
"""

from __future__ import annotations

import numpy as np

from calib.filter.branches import branch_signs
from calib.filter.fanuc_ls import turn_number
from calib.filter.krl import turn_of
from calib.filter.rotations import matrix_to_zyx_deg
from calib.kinematics import FloatArray
from calib.models import RobotModel
from filter_cells import planned_targets


def kuka_status(nominal: RobotModel, q_deg: FloatArray) -> list[int]:
    """``S`` of joints (n, 6) [deg]: bit 0 behind axis 1, bit 1 elbow up, bit 2 A5 < 0."""
    sh, el, wr = branch_signs(nominal, q_deg)
    return [int(sh[i] < 0) | int(el[i] > 0) << 1 | int(wr[i] < 0) << 2 for i in range(len(sh))]


def fanuc_config(nominal: RobotModel, q_deg: FloatArray) -> list[str]:
    """``'N U T, t4, t5, t6'`` of joints (n, 6) [deg]."""
    sh, el, wr = branch_signs(nominal, q_deg)
    out = []
    for i, q in enumerate(q_deg):
        letters = ("N" if wr[i] > 0 else "F") + " " + ("U" if el[i] > 0 else "D") + " " + (
            "T" if sh[i] > 0 else "B")  # fmt: skip
        out.append(f"{letters}, " + ", ".join(str(turn_number(q[j])) for j in (3, 4, 5)))
    return out


def _frame_text(f: FloatArray) -> str:
    a, b, c = matrix_to_zyx_deg(f[:3, :3])
    x, y, z = f[:3, 3]
    return f"{{X {x:.4f},Y {y:.4f},Z {z:.4f},A {a:.4f},B {b:.4f},C {c:.4f}}}"


def krl_program(nominal: RobotModel, q_plan: FloatArray, tool: FloatArray, work: FloatArray,
                name: str = "olp_path", tool_no: int = 3,
                base_no: int = 2) -> dict[str, str]:  # fmt: skip
    """``name.src``, ``name.dat`` and ``$config.dat`` (CRLF line ends; Latin-1 comments):
    every third target an inline ``LIN {…}`` after ``$TOOL``/``$BASE``, the others inline
    forms (``;FOLD`` with ``FDAT_ACT``) on ``.dat`` positions, the last two an array."""
    targets = planned_targets(nominal, q_plan, tool, work)
    status = kuka_status(nominal, q_plan)
    n = len(targets)
    config = [
        "&ACCESS RVP", "&REL 12", "DEFDAT  $CONFIG", ";FOLD BASISTECH GLOBALS",
        "DECL INT TOOL_NO_DUMMY=0", ";ENDFOLD (BASISTECH GLOBALS)", ";FOLD TOOL_DATA",
        "DECL FRAME TOOL_DATA[16]",
        "TOOL_DATA[1]={X 0.0,Y 0.0,Z 150.0,A 0.0,B 0.0,C 0.0}",
        f"TOOL_DATA[{tool_no}]={_frame_text(tool)} ; Schweißbrenner (EMULATED)",
        'TOOL_NAME[3,]="Brenner"', "TOOL_TYPE[3]=#NONE", ";ENDFOLD (TOOL_DATA)",
        ";FOLD BASE_DATA", "DECL FRAME BASE_DATA[32]",
        f"BASE_DATA[{base_no}]={_frame_text(work)} ; Tisch für Bauteil",
        "BASE_DATA[5]={X 100.0,Y 0.0,Z 0.0,A 0.0,B 0.0,C 0.0}", "BASE_TYPE[2]=#BASE",
        ";ENDFOLD (BASE_DATA)", "ENDDAT", "",
    ]  # fmt: skip
    dat = ["&ACCESS RVP", "&REL 12", f"DEFDAT  {name}", ";FOLD EXTERNAL DECLARATIONS;%{PE}",
           ";ENDFOLD (EXTERNAL DECLARATIONS)", ""]  # fmt: skip
    src = ["&ACCESS RVP", "&REL 12", "&PARAM EDITMASK = *", f"DEF {name}( )", ";FOLD INI;%{PE}",
           "  BAS (#INITMOV,0 )", ";ENDFOLD (INI)", "; Bahn geplant (OLP), Maße in mm", ""]  # fmt: skip
    array = [i for i in range(n) if i >= n - 2 and i % 3]
    if array:
        dat.append(f"DECL E6POS XPATH[{len(array)}]")
    for i, t in enumerate(targets):
        x, y, z = t[:3, 3]
        a, b, c = matrix_to_zyx_deg(t[:3, :3])
        s, tt = status[i], turn_of(q_plan[i])
        value = (f"X {x:.4f},Y {y:.4f},Z {z:.4f},A {a:.4f},B {b:.4f},C {c:.4f},S {s},T {tt},"
                 "E1 0.0,E2 0.0,E3 0.0,E4 0.0,E5 0.0,E6 0.0")  # fmt: skip
        if i % 3 == 0:
            src += [f"$TOOL=TOOL_DATA[{tool_no}]", f"$BASE = BASE_DATA[{base_no}]",
                    f"LIN {{X {x:.4f},Y {y:.4f},Z {z:.4f},A {a:.4f},B {b:.4f},C {c:.4f},"
                    f"S 'B{s:03b}',T 'B{tt:06b}'}} C_DIS ; Anfahrt"]  # fmt: skip
            continue
        ref = f"XPATH[{array.index(i) + 1}]" if i in array else f"XP{i}"
        if i in array:
            dat.append(f"{ref}={{{value}}}")
        else:
            dat.append(f"DECL E6POS XP{i}={{{value}}}")
        dat.append(f"DECL FDAT FP{i}={{TOOL_NO {tool_no},BASE_NO {base_no},IPO_FRAME #BASE,"
                   'POINT2[] " ",TQ_STATE FALSE}')  # fmt: skip
        dat.append(f"DECL PDAT PPDAT{i}={{VEL 100.000,ACC 100.000,APO_DIST 100.000}}")
        move = "PTP" if i % 2 else "LIN"
        src += [f";FOLD {move} P{i} Vel=100 % PDAT{i} Tool[{tool_no}]:Brenner Base[{base_no}]:"
                f"Tisch;%{{PE}}%R 8.3.31,%MKUKATPBASIS,%CMOVE,%V{move},%P 1:{move}",
                "$BWDSTART=FALSE", f"PDAT_ACT=PPDAT{i}", f"FDAT_ACT=FP{i}",
                f"BAS(#PTP_PARAMS,100)", f"{move} {ref} ", ";ENDFOLD", ""]  # fmt: skip
    dat.append("DECL E6AXIS XHOME={A1 0.0,A2 -60.0,A3 180.0,A4 0.0,A5 45.0,A6 0.0,E1 0.0}")
    src += ["PTP XHOME", "END", ""]
    dat += ["ENDDAT", ""]
    return {f"{name}.src": "\r\n".join(src), f"{name}.dat": "\r\n".join(dat),
            "$config.dat": "\r\n".join(config)}  # fmt: skip


def ls_program(nominal: RobotModel, q_plan: FloatArray, tool: FloatArray, work: FloatArray,
               name: str = "OLP_PATH", uf: int = 2, ut: int = 3) -> str:  # fmt: skip
    """An ``.LS`` program: every target a Cartesian ``P[n]`` in ``UF uf``, ``UT ut`` (odd ones
    with a ``GP2`` rail group), then ``HOME`` in joint form."""
    targets = planned_targets(nominal, q_plan, tool, work)
    config = fanuc_config(nominal, q_plan)
    n = len(targets)
    mn = [f"UFRAME_NUM={uf} ;", f"UTOOL_NUM={ut} ;", "PR[1]=LPOS ;"]
    pos: list[str] = []
    for i, t in enumerate(targets, start=1):
        mn.append(f"J P[{i}] 100% FINE ;" if i % 2 else f"L P[{i}] 500mm/sec CNT100 ;")
        x, y, z = t[:3, 3]
        r, p, w = matrix_to_zyx_deg(t[:3, :3])
        label = f'P[{i}:"pick {i}"]' if i == 2 else f"P[{i}]"
        pos += [f"{label}{{", "   GP1:", f"\tUF : {uf}, UT : {ut},\t\tCONFIG : '{config[i - 1]}',",
                f"\tX = {x:10.3f}  mm,\tY = {y:10.3f}  mm,\tZ = {z:10.3f}  mm,",
                f"\tW = {w:10.3f} deg,\tP = {p:10.3f} deg,\tR = {r:10.3f} deg"]  # fmt: skip
        if i % 2 == 0:
            pos += ["   GP2:", f"\tUF : {uf}, UT : {ut},", f"\tJ1= {250.0 * i:10.3f}  mm"]
        pos.append("};")
    mn.append(f"J P[{n + 1}:\"HOME\"] 50% FINE ;")
    pos += [f'P[{n + 1}:"HOME"]{{', "   GP1:", "\tUF : 0, UT : 3,",
            "\tJ1=     0.000 deg,\tJ2=   -60.000 deg,\tJ3=   180.000 deg,",
            "\tJ4=     0.000 deg,\tJ5=    45.000 deg,\tJ6=     0.000 deg", "};"]  # fmt: skip
    lines = [f"/PROG  {name}", "/ATTR", "OWNER\t\t= MNEDITOR;", 'COMMENT\t\t= "OLP";',
             f"LINE_COUNT\t= {len(mn)};", "PROTECT\t\t= READ_WRITE;",
             "DEFAULT_GROUP\t= 1,1,*,*,*;", "/MN"]  # fmt: skip
    lines += [f"{k:4d}:  {s}" if not s.startswith(("J ", "L ")) else f"{k:4d}:{s}"
              for k, s in enumerate(mn, start=1)]  # fmt: skip
    lines += ["/POS", *pos, "/END", ""]
    return "\n".join(lines)


def frames_toml(tool: FloatArray, work: FloatArray, uf: int = 2, ut: int = 3) -> str:
    """``--frames`` TOML with ``[uframe.uf]`` and ``[utool.ut]``."""

    def table(kind: str, n: int, f: FloatArray) -> str:
        r, p, w = matrix_to_zyx_deg(f[:3, :3])
        xyz = ", ".join(f"{v:.6f}" for v in f[:3, 3])
        return f"[{kind}.{n}]\nxyz_mm = [{xyz}]\nwpr_deg = [{w:.8f}, {p:.8f}, {r:.8f}]\n"

    return table("uframe", uf, work) + "\n" + table("utool", ut, tool)


__all__ = ["fanuc_config", "frames_toml", "krl_program", "kuka_status", "ls_program", "np"]
