"""EMULATED cells and offline-planned programs for the filter's tests and bench.

A true robot (:func:`calib.synthetic.make_true_cell`) is identified from noise-free cable
lengths shown to 0.01 mm; programs are then planned offline on the *nominal* model, as an
OLP system does: joints ``q_plan`` chosen away from singularities, the target
``T = W⁻¹ · FK_nominal(q_plan) · Tool`` written with the configuration of ``q_plan``.

The truth has no error in the terms cable lengths cannot observe (rotation about and shift
along base z, the joint-6 row): those are one rigid offset of the cell that the work-object
and tool calibration take up (docs/compensation.md), and no program filter can see them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from calib.dataset import make_samples
from calib.filter.branches import branch_signs, flange_frames
from calib.identify import IdentifyOptions, identify
from calib.ik import _errors_and_jacobian
from calib.kinematics import FloatArray
from calib.models import RobotModel, builtin_model
from calib.programs.rapid.filter import cfx_of
from calib.programs.rotations import frame, invert, matrix_to_quat_wxyz, matrix_to_rotvec
from calib.synthetic import TABLE_XII_D1, TrueCell, make_true_cell, random_poses_deg

#: The cable hook point of the emulated campaign, off the flange axis [mm].
HOOK_MM = (45.0, -30.0, 95.0)
#: Display resolution of the indicator [mm].
DISPLAY_MM = 0.01


@dataclass(frozen=True)
class Cell:
    """An EMULATED cell: nominal model, truth, and the identification's result.json."""

    nominal: RobotModel
    truth: TrueCell
    result: dict[str, Any]

    def true_flange(self, joints_deg: FloatArray) -> FloatArray:
        """The true robot's flange frames (n, 4, 4) [mm]."""
        dh = self.truth.theta[:24].reshape(6, 4).copy()
        dh[:, [0, 3]] = np.rad2deg(dh[:, [0, 3]])
        true_model = replace(self.nominal, dh_table=self.nominal.dh_table + dh)
        return flange_frames(true_model, joints_deg)


def make_cell(seed: int = 3, n_poses: int = 200, noise_mm: float = 0.0) -> Cell:
    """The EMULATED cell identified from ``n_poses`` lengths (Gaussian noise ``noise_mm``
    [mm] 1σ, then shown to :data:`DISPLAY_MM`)."""
    base = builtin_model("hsr-jr680")
    nominal = replace(base, tool_mm=np.array(HOOK_MM))
    errors = TABLE_XII_D1.copy()
    errors[0, 2] = errors[0, 3] = 0.0  # d1, theta1: unobservable (see the module docstring)
    errors[5] = 0.0  # the joint-6 row: absorbed in the hook point
    truth = make_true_cell(nominal, dh_errors_deg_mm=errors)
    rng = np.random.default_rng(seed)
    q = random_poses_deg(truth, n_poses, rng)
    lengths = truth.lengths_mm(q) + rng.normal(0.0, noise_mm, size=n_poses)
    lengths = np.round(lengths / DISPLAY_MM) * DISPLAY_MM
    result = identify(nominal, make_samples(q, lengths), IdentifyOptions(test_fraction=0.0))
    return Cell(nominal, truth, result.to_json())


def regular_poses(model: RobotModel, n: int, seed: int) -> FloatArray:
    """Joints (n, 6) [deg] away from singularities (pose-Jacobian condition < 25), within
    the limits, wrist bent by at least 15 deg."""
    rng = np.random.default_rng(seed)
    out = np.empty((0, 6))
    tool = np.array([0.0, 0.0, 200.0])
    while out.shape[0] < n:
        q = rng.uniform(
            [-150, -110, 75, -160, -110, -160], [150, 50, 285, 160, 110, 160], size=(4 * n, 6)
        )
        q = q[np.abs(q[:, 4]) > 15]
        eye = np.tile(np.eye(3), (q.shape[0], 1, 1))
        _, _, jac = _errors_and_jacobian(
            model, model.dh_internal(), np.deg2rad(q), tool, np.zeros((q.shape[0], 3)), eye
        )
        jac[:, 3:] *= 1000.0
        sv = np.linalg.svd(jac, compute_uv=False)
        out = np.vstack([out, q[sv[:, 0] < 25 * sv[:, -1]]])
    return out[:n]


def smooth_path(model: RobotModel, n: int, seed: int, step_deg: float = 3.0) -> FloatArray:
    """A path of n joints (n, 6) [deg] moving a few degrees per step from a regular pose (a
    UR program moves linearly from target to target: each takes the branch of the last)."""
    rng = np.random.default_rng(seed)
    start = regular_poses(model, 1, seed)[0]
    steps = rng.uniform(-step_deg, step_deg, size=(n, 6))
    steps[0] = 0.0
    out: FloatArray = start + np.cumsum(steps, axis=0)
    return out


def tool_frame(length_mm: float, tilt_deg: float = 20.0) -> FloatArray:
    """A tool: TCP ``length_mm`` out along a direction tilted ``tilt_deg`` about flange y,
    its frame tilted the same (4, 4) [mm]."""
    t = math.radians(tilt_deg)
    rot = np.array([[math.cos(t), 0, math.sin(t)], [0, 1, 0], [-math.sin(t), 0, math.cos(t)]])
    return frame(rot @ np.array([0.0, 0.0, length_mm]) + np.array([8.0, -5.0, 0.0]), rot)


def work_frame() -> FloatArray:
    """A work object on a table in front of the robot, turned 30 deg about z [mm]."""
    a = math.radians(30.0)
    rot = np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])
    return frame(np.array([900.0, -250.0, 300.0]), rot)


def planned_targets(
    nominal: RobotModel, q_plan: FloatArray, tool: FloatArray, work: FloatArray
) -> FloatArray:
    """Targets (n, 4, 4) in ``work`` of ``tool`` that the nominal controller reaches at
    ``q_plan``."""
    out: FloatArray = invert(work) @ flange_frames(nominal, q_plan) @ tool
    return out


#: The object frame inside the work object (RAPID's oframe): the work object is uframe · oframe.
OFRAME = frame(
    np.array([35.0, -20.0, 12.0]), np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
)


def rapid_confdata(nominal: RobotModel, q_deg: FloatArray) -> list[tuple[int, int, int, int]]:
    """``[cf1, cf4, cf6, cfx]`` of joints (n, 6) [deg] (calib.programs.rapid.filter's reading)."""
    sh, el, wr = branch_signs(nominal, q_deg)
    out = []
    for i, q in enumerate(q_deg):
        cfx = cfx_of(sh[i], el[i], wr[i])
        out.append((math.floor(q[0] / 90), math.floor(q[3] / 90), math.floor(q[5] / 90), cfx))
    return out


def _quat(rot: FloatArray) -> list[float]:
    return [float(v) for v in matrix_to_quat_wxyz(rot)]


def rapid_module(
    nominal: RobotModel,
    q_plan: FloatArray,
    tool: FloatArray,
    work: FloatArray,
    name: str = "OLP_PATH",
    newline: str = "\n",
) -> str:
    """A RAPID module as an OLP system writes it: tooldata, wobjdata, one robtarget per
    target (odd ones over several lines), and MoveL/MoveJ instructions."""
    targets = planned_targets(nominal, q_plan, tool, work)
    conf = rapid_confdata(nominal, q_plan)

    def pose(f: FloatArray) -> str:
        p = ",".join(f"{v:.3f}" for v in f[:3, 3])
        return f"[{p}],[" + ",".join(f"{v:.7f}" for v in _quat(f[:3, :3])) + "]"

    lines = [
        f"MODULE {name}",
        "    ! planned offline (EMULATED)",
        f"    PERS tooldata tOlp:=[TRUE,[{pose(tool)}],[3.5,[0,0,80],[1,0,0,0],0,0,0]];",
        f'    TASK PERS wobjdata wOlp:=[FALSE,TRUE,"",[{pose(work @ invert(OFRAME))}],'
        f"[{pose(OFRAME)}]];",
    ]
    for i, t in enumerate(targets):
        p = ",".join(f"{v:.3f}" for v in t[:3, 3])
        q = ",".join(f"{v:.7f}" for v in _quat(t[:3, :3]))
        cf = ",".join(str(c) for c in conf[i])
        ext = "[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]"
        if i % 2:
            lines.append(
                f"    CONST robtarget p{i}:=[[{p}],\n        [{q}],\n        [{cf}],"
                f"\n        {ext}];"
            )
        else:
            lines.append(f"    CONST robtarget p{i}:=[[{p}],[{q}],[{cf}],{ext}];")
    lines.append("    PROC main()")
    for i in range(len(targets)):
        move = "MoveJ" if i % 3 == 0 else "MoveL"
        lines.append(f"        {move} p{i}, v200, fine, tOlp\\WObj:=wOlp;")
    lines += ["    ENDPROC", "ENDMODULE", ""]
    return newline.join(lines)


def urscript(
    nominal: RobotModel, q_plan: FloatArray, tool: FloatArray, polyscope: bool = True
) -> str:
    """A URScript program (base frame): PolyScope-style ``Waypoint_n_p``/``_q`` globals and
    ``movel``/``movej(get_inverse_kin(…, qnear=…))``, with ``set_tcp``."""
    targets = flange_frames(nominal, q_plan) @ tool
    tcp = matrix_to_rotvec(tool[:3, :3])
    tcp_text = (
        ", ".join(f"{v / 1000:.6f}" for v in tool[:3, 3])
        + ", "
        + ", ".join(f"{v:.6f}" for v in tcp)
    )
    lines = ["def olp_program():", f"  set_tcp(p[{tcp_text}])"]
    if not polyscope:  # a plain script starts from a joint move (its "q" for the first movel)
        home = ", ".join(repr(float(v)) for v in np.deg2rad(q_plan[0] + 2.0))
        lines.append(f"  movej([{home}], a=1.0, v=0.5)")
    for i, t in enumerate(targets):
        pos = [v / 1000 for v in t[:3, 3]]
        rv = matrix_to_rotvec(t[:3, :3])
        text = ", ".join(f"{v:.9f}" for v in [*pos, *rv])
        if polyscope:
            lines.append(f"  global Waypoint_{i + 1}_p=p[{text}]")
            qs = ", ".join(repr(float(v)) for v in np.deg2rad(q_plan[i]))
            lines.append(f"  global Waypoint_{i + 1}_q=[{qs}]")
    for i in range(len(targets)):
        if polyscope:
            if i % 2:
                lines.append(f"  movel(Waypoint_{i + 1}_p, a=1.2, v=0.25)")
            else:
                lines.append(
                    f"  movej(get_inverse_kin(Waypoint_{i + 1}_p, qnear=Waypoint_"
                    f"{i + 1}_q), a=1.39, v=1.04)"
                )
        else:
            pos = [v / 1000 for v in targets[i][:3, 3]]
            rv = matrix_to_rotvec(targets[i][:3, :3])
            text = ", ".join(f"{v:.9f}" for v in [*pos, *rv])
            lines.append(f"  movel(p[{text}], a=1.2, v=0.25)")
    lines += ["end", ""]
    return "\n".join(lines)
