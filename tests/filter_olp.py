"""EMULATED offline-planned KRL and Fanuc LS programs for the filter's tests.

The targets come from :func:`filter_cells.planned_targets` (joints ``q_plan`` on the
nominal model); the status/turn and CONFIG fields are those of ``q_plan`` as
:mod:`calib.programs.krl.filter` and :mod:`calib.programs.fanuc.filter` read them. The shapes
follow what
KUKA's inline forms and Fanuc's ASCII export write: ``;FOLD`` blocks with ``FDAT_ACT``,
``DECL E6POS`` with ``S``/``T``, ``$config.dat`` with ``TOOL_DATA``/``BASE_DATA``; ``/POS``
entries with ``GP1`` (Cartesian or joint form) and ``GP2``.
"""

from __future__ import annotations

import numpy as np
from filter_cells import Cell, planned_targets

from calib.filter.branches import branch_signs, flange_frames, nominal_solutions
from calib.filter.run import FilterRun
from calib.filter.select import choose
from calib.kinematics import FloatArray
from calib.models import RobotModel
from calib.programs.fanuc.config import config_text
from calib.programs.krl.filter import turn_of
from calib.programs.rotations import invert, matrix_to_zyx_deg, rotation_angle_deg
from calib.programs.sites import Dialect, FrameTables, Source, Target


def kuka_status(nominal: RobotModel, q_deg: FloatArray) -> list[int]:
    """``S`` of joints (n, 6) [deg]: bit 0 behind axis 1, bit 1 elbow up, bit 2 A5 < 0."""
    sh, el, wr = branch_signs(nominal, q_deg)
    return [int(sh[i] < 0) | int(el[i] > 0) << 1 | int(wr[i] < 0) << 2 for i in range(len(sh))]


def fanuc_config(nominal: RobotModel, q_deg: FloatArray) -> list[str]:
    """``'F U T, t1, t4, t6'`` of joints (n, 6) [deg] (the rule of calib.programs.fanuc.config)."""
    sh, el, _wr = branch_signs(nominal, q_deg)
    return [config_text(q, int(sh[i]), int(el[i])) for i, q in enumerate(q_deg)]


def _frame_text(f: FloatArray) -> str:
    a, b, c = matrix_to_zyx_deg(f[:3, :3])
    x, y, z = f[:3, 3]
    return f"{{X {x:.4f},Y {y:.4f},Z {z:.4f},A {a:.4f},B {b:.4f},C {c:.4f}}}"


def krl_program(
    nominal: RobotModel,
    q_plan: FloatArray,
    tool: FloatArray,
    work: FloatArray,
    name: str = "olp_path",
    tool_no: int = 3,
    base_no: int = 2,
) -> dict[str, str]:
    """``name.src``, ``name.dat`` and ``$config.dat`` (CRLF line ends; Latin-1 comments):
    every third target an inline ``LIN {…}`` after ``$TOOL``/``$BASE``, the others inline
    forms (``;FOLD`` with ``FDAT_ACT``) on ``.dat`` positions, the last two an array."""
    targets = planned_targets(nominal, q_plan, tool, work)
    status = kuka_status(nominal, q_plan)
    n = len(targets)
    config = [
        "&ACCESS RVP",
        "&REL 12",
        "DEFDAT  $CONFIG",
        ";FOLD BASISTECH GLOBALS",
        "DECL INT TOOL_NO_DUMMY=0",
        ";ENDFOLD (BASISTECH GLOBALS)",
        ";FOLD TOOL_DATA",
        "DECL FRAME TOOL_DATA[16]",
        "TOOL_DATA[1]={X 0.0,Y 0.0,Z 150.0,A 0.0,B 0.0,C 0.0}",
        f"TOOL_DATA[{tool_no}]={_frame_text(tool)} ; Schweißbrenner (EMULATED)",
        'TOOL_NAME[3,]="Brenner"',
        "TOOL_TYPE[3]=#NONE",
        ";ENDFOLD (TOOL_DATA)",
        ";FOLD BASE_DATA",
        "DECL FRAME BASE_DATA[32]",
        f"BASE_DATA[{base_no}]={_frame_text(work)} ; Tisch für Bauteil",
        "BASE_DATA[5]={X 100.0,Y 0.0,Z 0.0,A 0.0,B 0.0,C 0.0}",
        "BASE_TYPE[2]=#BASE",
        ";ENDFOLD (BASE_DATA)",
        "ENDDAT",
        "",
    ]
    dat = [
        "&ACCESS RVP",
        "&REL 12",
        f"DEFDAT  {name}",
        ";FOLD EXTERNAL DECLARATIONS;%{PE}",
        ";ENDFOLD (EXTERNAL DECLARATIONS)",
        "",
    ]
    src = [
        "&ACCESS RVP",
        "&REL 12",
        "&PARAM EDITMASK = *",
        f"DEF {name}( )",
        ";FOLD INI;%{PE}",
        "  BAS (#INITMOV,0 )",
        ";ENDFOLD (INI)",
        "; Bahn geplant (OLP), Maße in mm",
        "",
    ]
    array = [i for i in range(n) if i >= n - 2 and i % 3]
    if array:
        dat.append(f"DECL E6POS XPATH[{len(array)}]")
    for i, t in enumerate(targets):
        x, y, z = t[:3, 3]
        a, b, c = matrix_to_zyx_deg(t[:3, :3])
        s, tt = status[i], turn_of(q_plan[i])
        value = (
            f"X {x:.4f},Y {y:.4f},Z {z:.4f},A {a:.4f},B {b:.4f},C {c:.4f},S {s},T {tt},"
            "E1 0.0,E2 0.0,E3 0.0,E4 0.0,E5 0.0,E6 0.0"
        )
        if i % 3 == 0:
            src += [
                f"$TOOL=TOOL_DATA[{tool_no}]",
                f"$BASE = BASE_DATA[{base_no}]",
                f"LIN {{X {x:.4f},Y {y:.4f},Z {z:.4f},A {a:.4f},B {b:.4f},C {c:.4f},"
                f"S 'B{s:03b}',T 'B{tt:06b}'}} C_DIS ; Anfahrt",
            ]
            continue
        ref = f"XPATH[{array.index(i) + 1}]" if i in array else f"XP{i}"
        if i in array:
            dat.append(f"{ref}={{{value}}}")
        else:
            dat.append(f"DECL E6POS XP{i}={{{value}}}")
        dat.append(
            f"DECL FDAT FP{i}={{TOOL_NO {tool_no},BASE_NO {base_no},IPO_FRAME #BASE,"
            'POINT2[] " ",TQ_STATE FALSE}'
        )
        dat.append(f"DECL PDAT PPDAT{i}={{VEL 100.000,ACC 100.000,APO_DIST 100.000}}")
        move = "PTP" if i % 2 else "LIN"
        src += [
            f";FOLD {move} P{i} Vel=100 % PDAT{i} Tool[{tool_no}]:Brenner Base[{base_no}]:"
            f"Tisch;%{{PE}}%R 8.3.31,%MKUKATPBASIS,%CMOVE,%V{move},%P 1:{move}",
            "$BWDSTART=FALSE",
            f"PDAT_ACT=PPDAT{i}",
            f"FDAT_ACT=FP{i}",
            "BAS(#PTP_PARAMS,100)",
            f"{move} {ref} ",
            ";ENDFOLD",
            "",
        ]
    dat.append("DECL E6AXIS XHOME={A1 0.0,A2 -60.0,A3 180.0,A4 0.0,A5 45.0,A6 0.0,E1 0.0}")
    src += ["PTP XHOME", "END", ""]
    dat += ["ENDDAT", ""]
    return {
        f"{name}.src": "\r\n".join(src),
        f"{name}.dat": "\r\n".join(dat),
        "$config.dat": "\r\n".join(config),
    }


def ls_program(
    nominal: RobotModel,
    q_plan: FloatArray,
    tool: FloatArray,
    work: FloatArray,
    name: str = "OLP_PATH",
    uf: int = 2,
    ut: int = 3,
) -> str:
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
        pos += [
            f"{label}{{",
            "   GP1:",
            f"\tUF : {uf}, UT : {ut},\t\tCONFIG : '{config[i - 1]}',",
            f"\tX = {x:10.3f}  mm,\tY = {y:10.3f}  mm,\tZ = {z:10.3f}  mm,",
            f"\tW = {w:10.3f} deg,\tP = {p:10.3f} deg,\tR = {r:10.3f} deg",
        ]
        if i % 2 == 0:
            pos += ["   GP2:", f"\tUF : {uf}, UT : {ut},", f"\tJ1= {250.0 * i:10.3f}  mm"]
        pos.append("};")
    mn.append(f'J P[{n + 1}:"HOME"] 50% FINE ;')
    pos += [
        f'P[{n + 1}:"HOME"]{{',
        "   GP1:",
        "\tUF : 0, UT : 3,",
        "\tJ1=     0.000 deg,\tJ2=   -60.000 deg,\tJ3=   180.000 deg,",
        "\tJ4=     0.000 deg,\tJ5=    45.000 deg,\tJ6=     0.000 deg",
        "};",
    ]
    lines = [
        f"/PROG  {name}",
        "/ATTR",
        "OWNER\t\t= MNEDITOR;",
        'COMMENT\t\t= "OLP";',
        f"LINE_COUNT\t= {len(mn)};",
        "PROTECT\t\t= READ_WRITE;",
        "DEFAULT_GROUP\t= 1,1,*,*,*;",
        "/MN",
    ]
    lines += [
        f"{k:4d}:  {s}" if not s.startswith(("J ", "L ")) else f"{k:4d}:{s}"
        for k, s in enumerate(mn, start=1)
    ]
    lines += ["/POS", *pos, "/END", ""]
    return "\n".join(lines)


def frames_toml(tool: FloatArray, work: FloatArray, uf: int = 2, ut: int = 3) -> str:
    """``--frames`` TOML with ``[uframe.uf]`` and ``[utool.ut]``."""

    def table(kind: str, n: int, f: FloatArray) -> str:
        r, p, w = matrix_to_zyx_deg(f[:3, :3])
        xyz = ", ".join(f"{v:.6f}" for v in f[:3, 3])
        return f"[{kind}.{n}]\nxyz_mm = [{xyz}]\nwpr_deg = [{w:.8f}, {p:.8f}, {r:.8f}]\n"

    return table("uframe", uf, work) + "\n" + table("utool", ut, tool)


def _executed(cell: Cell, targets: list[Target]) -> tuple[FloatArray, FloatArray]:
    """Where the true robot puts each target's tool (Cartesian: TCP in the work object;
    joint: the flange in the base), executed as the nominal controller does: (n, 4, 4)
    frames, and the joints it commands (n, 6) [deg] (NaN when it finds none)."""
    q = np.full((len(targets), 6), np.nan)
    cart = [i for i, t in enumerate(targets) if t.kind == "cartesian"]
    for i, t in enumerate(targets):
        if t.kind == "joint":
            q[i] = t.joints_deg
    if cart:
        fl = np.stack(
            [
                targets[i].uses[0].work
                @ targets[i].pose  # type: ignore[operator]
                @ invert(targets[i].uses[0].tool)
                for i in cart
            ]
        )  # type: ignore[arg-type]
        sol = nominal_solutions(cell.nominal, fl)
        idx, _ = choose(sol, [targets[i].configuration for i in cart])
        for r, i in enumerate(cart):
            if idx[r] >= 0:
                q[i] = sol.joints_deg[r, idx[r]]
    true_fl = cell.true_flange(np.nan_to_num(q))
    out = true_fl.copy()
    for i in cart:
        use = targets[i].uses[0]
        out[i] = invert(use.work) @ true_fl[i] @ use.tool  # type: ignore[arg-type]
    return out, q


def accuracy(
    cell: Cell, dialect: Dialect, files: dict[str, bytes], run: FilterRun, frames: FrameTables
) -> dict[str, FloatArray]:
    """Per corrected target, the true robot's error against the intended pose: unfiltered,
    filtered (the written numbers, the controller's branch) and the floor (the exact
    calibrated joints ``q*``): ``{"<which>_mm": (n,), "<which>_deg": (n,)}``."""
    before = dialect.parse([Source.from_bytes(k, v) for k, v in files.items()], frames)
    after = dialect.parse(
        [Source.from_bytes(k, v) for k, v in run.outputs.items() if k in files], frames
    )
    by_key = {(t.file, t.name): c for t, c in zip(run.targets, run.corrections, strict=True)}
    keep = [k for k, t in enumerate(before) if by_key[(t.file, t.name)].status == "corrected"]
    before = [before[k] for k in keep]
    after = [after[k] for k in keep]
    intended = np.stack(
        [
            t.pose
            if t.kind == "cartesian"
            else flange_frames(cell.nominal, np.asarray(t.joints_deg)[None])[0]
            for t in before
        ]
    )
    out: dict[str, FloatArray] = {}
    floor = [t for t in before]
    star = {id(t): by_key[(t.file, t.name)].joints_deg for t in floor}
    for which, ts in (("unfiltered", before), ("filtered", after)):
        got, q = _executed(cell, ts)
        assert np.all(np.isfinite(q)), f"{which}: the controller finds no solution"
        out[f"{which}_mm"] = np.linalg.norm(got[:, :3, 3] - intended[:, :3, 3], axis=1)
        out[f"{which}_deg"] = rotation_angle_deg(intended[:, :3, :3], got[:, :3, :3])
    q_star = np.array([star[id(t)] for t in floor])
    true_fl = cell.true_flange(q_star)
    got = true_fl.copy()
    for i, t in enumerate(floor):
        if t.kind == "cartesian":
            got[i] = invert(t.uses[0].work) @ true_fl[i] @ t.uses[0].tool  # type: ignore[arg-type]
    out["floor_mm"] = np.linalg.norm(got[:, :3, 3] - intended[:, :3, 3], axis=1)
    out["floor_deg"] = rotation_angle_deg(intended[:, :3, :3], got[:, :3, :3])
    return out


def rms(v: FloatArray) -> float:
    return float(np.sqrt(np.mean(np.square(v))))


__all__ = [
    "accuracy",
    "fanuc_config",
    "frames_toml",
    "krl_program",
    "kuka_status",
    "ls_program",
    "rms",
]
