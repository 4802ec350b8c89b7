"""Compensation ("program filtering"): corrected joint targets from a calibrated model.

No robot controller accepts new DH parameters, so a calibration is applied by correcting the
program: for every target, the joints that bring the *calibrated* model's tool point (and, in
pose mode, its orientation) to where the *nominal* model — the controller's model — says the
target is. The robot then really goes where the program meant.

Targets
    * Nominal joint angles ``q1..q6`` [deg] (taught points, or an offline program solved with
      the nominal model): the target is the nominal model's tool pose at those joints, and the
      IK on the calibrated model starts from those joints.
    * Cartesian ``x, y, z`` [mm] (and ``rx, ry, rz`` [deg] in pose mode) in the robot's base
      frame. First the nominal joints are found by IK on the *nominal* model, seeded from a
      user seed (the seed chooses the branch: shoulder, elbow, wrist; a controller would use
      its configuration flags). Then the calibrated IK starts from that nominal solution, as
      for joint targets. The corrected Cartesian target (the nominal model's pose at the
      corrected joints) is reported too, for controllers that only take Cartesian programs.
      In position mode a Cartesian target leaves the orientation free: the nominal IK moves
      from the seed with the smallest joint change, so give a seed with the intended wrist
      orientation (or use pose mode).

**Euler convention** of ``rx, ry, rz``: fixed-axis X-Y-Z, ``R = Rz(rz) · Ry(ry) · Rx(rx)``
(equivalently intrinsic Z-Y'-X''); scipy's ``Rotation.from_euler("xyz")``, URDF's ``rpy``,
Fanuc's W, P, R; KUKA's A, B, C are ``rz, ry, rx``. The emulated cell reports the same angles.

IK (:mod:`calib.ik`)
    Damped least squares, ``Δq = Jᵀ (J Jᵀ + λ² I)⁻¹ e`` (joint-weighted), with the geometric
    Jacobian of the tool point (position mode, 3 rows) or of the tool pose (pose mode, 6 rows:
    the rotation error ``log(R_target Rᵀ)`` [rad] weighted by ``rotation_weight_mm_per_rad``);
    each step is capped to ``max_step_deg`` per joint. All targets are solved at once (numpy
    batches over the targets still active), far faster than a per-target loop
    (``bench/compensate_results.md``).
    In position mode the three spare degrees of freedom are used minimally: DLS from the
    nominal joints gives the smallest joint correction.

Flags per row: ``ik_failed`` (residual above tolerance after ``max_iterations``),
``outside_limits:J<j>=<value><<limit>`` (a corrected joint outside the model's limits, one
flag per joint), ``branch_jump`` (the corrected joints left the nominal joints' branch, by
the correction engine's one definition, :func:`calib.filter.select.left_branch`, for joint
moves: a joint moved by more than ``branch_threshold_deg``, or the wrist flipped, joint 5
changing sign with both sides at least ``wrist_flip_min_deg`` from 0); for Cartesian targets
also ``nominal_ik_failed`` and ``nominal_wrist_flip`` (the nominal solution's wrist differs
from the seed's, by the same rule).

What compensation cannot remove
    Cable lengths cannot observe a rotation of the robot about its base z axis, a shift along
    that axis, or the joint-6 terms (they are absorbed into the cable hook point). The
    calibrated model keeps these at their nominal values, so the corrected program still
    carries them as one rigid offset of the whole robot (and, for a tool point away from the
    hook, of the tool). The user's base or work-object calibration (and tool calibration)
    takes it up. :attr:`CompensateResult.note` says so.

    Pose mode corrects the orientation toward the calibrated model's flange orientation, which
    cable lengths observe only through the hook point's lever; with a hook near the flange
    axis it is weakly identified (on the virtual cell of ``bench/compensate_bench.py`` the
    true orientation error grows: bench/compensate_results.md). The note says so in pose mode.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from scipy.spatial.transform import Rotation

from calib.filter import select as engine
from calib.ik import IKOptions, solve_ik, tool_pose
from calib.kinematics import N_JOINTS, FloatArray
from calib.models import RobotModel

Mode = Literal["position", "pose"]
#: scipy's sequence for fixed-axis X-Y-Z angles (lower case = extrinsic).
EULER_SEQUENCE = "xyz"
JOINT_COLUMNS = tuple(f"q{j + 1}" for j in range(N_JOINTS))
POSITION_COLUMNS = ("x", "y", "z")
ROTATION_COLUMNS = ("rx", "ry", "rz")
NOTE = (
    "Not compensated: a rotation of the robot about its base z axis, a shift along it, and the "
    "joint-6 terms (absorbed into the cable hook point) are unobservable from cable lengths; "
    "they remain as one rigid offset of the cell (and of a tool point away from the hook), "
    "which the base / work-object (and tool) calibration on the controller takes up."
)

POSE_NOTE = (
    " Pose mode: the flange orientation is observed from cable lengths only through the lever "
    "of the hook point; with a hook near the flange axis the joint-5 terms trade against the "
    "hook point and the calibrated orientation can be off by about a degree (see "
    "bench/compensate_results.md). Prefer position mode unless the campaign's hook sat well "
    "off the flange axis."
)


@dataclass(frozen=True)
class CompensateOptions:
    """Options of :func:`compensate`.

    Attributes
    ----------
    mode : {"position", "pose"}
        Match the tool point only, or the tool point and the flange orientation.
    tool_mm : tuple of 3 floats
        Tool point (TCP) in the flange frame [mm], the same in both models; (0, 0, 0) is the
        flange centre.
    ik : IKOptions
        Iterations, tolerances, damping, step cap and joint weights of the DLS
        (:mod:`calib.ik`).
    branch_threshold_deg : float
        A joint moved further than this from the nominal joints flags ``branch_jump`` [deg]
        (default: the engine's :data:`calib.filter.select.BRANCH_JUMP_DEG`).
    wrist_flip_min_deg : float
        Joint 5 must be this far from 0 on both sides for a sign change to count as a wrist
        flip [deg] (default: :data:`calib.filter.select.WRIST_SINGULARITY_DEG`).
    """

    mode: Mode = "position"
    tool_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    ik: IKOptions = field(default_factory=IKOptions)
    branch_threshold_deg: float = engine.BRANCH_JUMP_DEG
    wrist_flip_min_deg: float = engine.WRIST_SINGULARITY_DEG

    def __post_init__(self) -> None:
        if self.mode not in ("position", "pose"):
            raise ValueError(f"mode must be 'position' or 'pose', got {self.mode!r}")
        if len(self.tool_mm) != 3 or not all(math.isfinite(v) for v in self.tool_mm):
            raise ValueError(f"tool_mm must be 3 finite numbers, got {self.tool_mm!r}")
        if not (math.isfinite(self.branch_threshold_deg) and self.branch_threshold_deg > 0):
            raise ValueError(
                f"branch_threshold_deg must be positive, got {self.branch_threshold_deg!r}"
            )
        if not 0 <= self.wrist_flip_min_deg < 90:
            raise ValueError(
                f"wrist_flip_min_deg must be in [0, 90), got {self.wrist_flip_min_deg}"
            )


@dataclass(frozen=True)
class JointTargets:
    """Targets given as nominal joint angles, ``joints_deg`` shape (n, 6) [deg]."""

    joints_deg: FloatArray


@dataclass(frozen=True)
class CartesianTargets:
    """Targets in the base frame.

    Attributes
    ----------
    position_mm : ndarray, shape (n, 3)
    rotation_deg : ndarray, shape (n, 3) or None
        ``rx, ry, rz`` (fixed-axis X-Y-Z, see the module docstring); required in pose mode.
    seed_deg : ndarray, shape (6,) or (n, 6)
        Start of the nominal IK: chooses the branch.
    """

    position_mm: FloatArray
    rotation_deg: FloatArray | None
    seed_deg: FloatArray


Targets = JointTargets | CartesianTargets


def _limit_flags(model: RobotModel, joints_deg: FloatArray) -> list[list[str]]:
    """Per row, one ``outside_limits`` flag per joint beyond the model's limits, naming the
    joint, its value and the limit crossed, e.g. ``outside_limits:J3=-80.000<-75.000``."""
    limits = model.joint_limits_deg
    out: list[list[str]] = [[] for _ in range(joints_deg.shape[0])]
    if limits is None:
        return out
    for i, j in zip(*np.nonzero(joints_deg < limits[:, 0]), strict=True):
        out[i].append(f"outside_limits:J{j + 1}={joints_deg[i, j]:.3f}<{limits[j, 0]:.3f}")
    for i, j in zip(*np.nonzero(joints_deg > limits[:, 1]), strict=True):
        out[i].append(f"outside_limits:J{j + 1}={joints_deg[i, j]:.3f}>{limits[j, 1]:.3f}")
    return out


def default_seed_deg(model: RobotModel) -> FloatArray:
    """The IK seed of Cartesian targets when none is given, shape (6,) [deg]: the middle of
    each joint's limits (zero without limits), inside the limits by construction."""
    if model.joint_limits_deg is None:
        return np.zeros(6)
    out: FloatArray = np.round(model.joint_limits_deg.mean(axis=1), 3)
    return out


#: Decimals of the floats in :meth:`CompensateResult.to_csv` (0.001 deg / 0.001 mm).
CSV_DECIMALS = 3


def _csv_cell(value: Any) -> Any:
    if isinstance(value, float):
        return "" if not math.isfinite(value) else f"{value:.{CSV_DECIMALS}f}"
    return value


@dataclass
class CompensateResult:
    """Corrected targets. Arrays have one row per target.

    Attributes
    ----------
    mode : {"position", "pose"}
    kind : {"joints", "cartesian"}
    tool_mm : ndarray, shape (3,)
    nominal_joints_deg : ndarray, shape (n, 6)
        The program's joints (given, or nominal IK of the Cartesian targets).
    corrected_joints_deg : ndarray, shape (n, 6)
        What to send to the controller.
    position_residual_mm, rotation_residual_deg : ndarray, shape (n,)
        Calibrated model at the corrected joints vs the target (rotation NaN in position mode).
    iterations : ndarray of int, shape (n,)
        Calibrated-model IK iterations (plus the nominal IK's, for Cartesian targets).
    uncompensated_error_mm : ndarray, shape (n,)
        The calibrated model's position error at the uncorrected joints: what compensation
        removes.
    corrected_position_mm, corrected_rotation_deg : ndarray, shape (n, 3)
        The nominal model's pose at the corrected joints: the corrected Cartesian target.
    flags : list of list of str
    note : str
    """

    mode: Mode
    kind: Literal["joints", "cartesian"]
    tool_mm: FloatArray
    nominal_joints_deg: FloatArray
    corrected_joints_deg: FloatArray
    position_residual_mm: FloatArray
    rotation_residual_deg: FloatArray
    iterations: np.ndarray
    uncompensated_error_mm: FloatArray
    corrected_position_mm: FloatArray
    corrected_rotation_deg: FloatArray
    flags: list[list[str]]
    note: str = NOTE
    summary: dict[str, Any] = field(default_factory=dict)

    @property
    def ok(self) -> np.ndarray:
        """Rows without flags, shape (n,) bool."""
        return np.array([not f for f in self.flags], dtype=bool)

    def csv_rows(self) -> list[dict[str, Any]]:
        """One mapping per target, in column order (``index`` 0-based)."""
        rows: list[dict[str, Any]] = []
        for i in range(len(self.flags)):
            row: dict[str, Any] = {"index": i}
            row |= {
                f"{c}_nominal": float(v)
                for c, v in zip(JOINT_COLUMNS, self.nominal_joints_deg[i], strict=True)
            }
            row |= {
                c: float(v)
                for c, v in zip(JOINT_COLUMNS, self.corrected_joints_deg[i], strict=True)
            }
            row |= {
                c: float(v)
                for c, v in zip(POSITION_COLUMNS, self.corrected_position_mm[i], strict=True)
            }
            row |= {
                c: float(v)
                for c, v in zip(ROTATION_COLUMNS, self.corrected_rotation_deg[i], strict=True)
            }
            row["max_correction_deg"] = float(
                np.max(np.abs(self.corrected_joints_deg[i] - self.nominal_joints_deg[i]))
            )
            row["residual_mm"] = float(self.position_residual_mm[i])
            row["residual_deg"] = float(self.rotation_residual_deg[i])
            row["uncompensated_error_mm"] = float(self.uncompensated_error_mm[i])
            row["iterations"] = int(self.iterations[i])
            row["flags"] = ";".join(self.flags[i])
            rows.append(row)
        return rows

    def to_csv(self) -> str:
        """CSV text of :meth:`csv_rows` (``q1..q6`` are the corrected joints): angles and
        lengths to :data:`CSV_DECIMALS` decimals (0.001 deg / 0.001 mm, finer than any
        controller takes), a value that is not a number (no solution) left empty."""
        rows = [{k: _csv_cell(v) for k, v in r.items()} for r in self.csv_rows()]
        out = io.StringIO()
        if rows:
            writer = csv.DictWriter(out, fieldnames=list(rows[0]), lineterminator="\n")
            writer.writeheader()
            writer.writerows(rows)
        return out.getvalue()

    def to_json(self) -> dict[str, Any]:
        """JSON-able mapping: ``mode, kind, tool_mm, note, summary, rows`` (NaN → None)."""
        rows = [
            {k: (None if isinstance(v, float) and math.isnan(v) else v) for k, v in r.items()}
            for r in self.csv_rows()
        ]
        return {
            "mode": self.mode,
            "kind": self.kind,
            "tool_mm": [float(v) for v in self.tool_mm],
            "note": self.note,
            "summary": self.summary,
            "rows": rows,
        }


def _check_targets(nominal: RobotModel, targets: Targets, mode: Mode) -> FloatArray:
    """Validate the targets; returns the seed ``(n, 6)`` [deg] of the nominal stage."""
    if isinstance(targets, JointTargets):
        q = np.asarray(targets.joints_deg, dtype=float)
        if q.ndim != 2 or q.shape[1] != N_JOINTS or q.shape[0] == 0:
            raise ValueError(f"joints_deg: expected shape (n, 6) with n >= 1, got {q.shape}")
        bad = np.argwhere(~np.isfinite(q))
        if bad.size:
            raise ValueError(f"joints_deg: row {bad[0][0]}, q{bad[0][1] + 1} is not finite")
        return q
    pos = np.asarray(targets.position_mm, dtype=float)
    if pos.ndim != 2 or pos.shape[1] != 3 or pos.shape[0] == 0:
        raise ValueError(f"position_mm: expected shape (n, 3) with n >= 1, got {pos.shape}")
    if not np.all(np.isfinite(pos)):
        raise ValueError(
            f"position_mm: row {int(np.argwhere(~np.isfinite(pos))[0][0])} is not finite"
        )
    if mode == "pose":
        if targets.rotation_deg is None:
            raise ValueError("rotation_deg: required in pose mode (rx, ry, rz per target)")
        rot = np.asarray(targets.rotation_deg, dtype=float)
        if rot.shape != pos.shape or not np.all(np.isfinite(rot)):
            raise ValueError(f"rotation_deg: expected finite shape {pos.shape}, got {rot.shape}")
    seed = np.asarray(targets.seed_deg, dtype=float)
    if seed.shape == (N_JOINTS,):
        seed = np.tile(seed, (pos.shape[0], 1))
    if seed.shape != (pos.shape[0], N_JOINTS) or not np.all(np.isfinite(seed)):
        raise ValueError(
            f"seed_deg: expected finite shape (6,) or ({pos.shape[0]}, 6), got {seed.shape}"
        )
    return seed


def compensate(
    nominal: RobotModel,
    calibrated: RobotModel,
    targets: Targets,
    options: CompensateOptions | None = None,
) -> CompensateResult:
    """Corrected joints that make the calibrated robot reach the nominal targets.

    Parameters
    ----------
    nominal : RobotModel
        The controller's model (and joint limits for the flags).
    calibrated : RobotModel
        The calibrated model, e.g. :func:`calib.export.model_from_result`. Only its DH table
        and convention are used; ``options.tool_mm`` is the tool point of both models.
    targets : JointTargets or CartesianTargets
    options : CompensateOptions

    Raises
    ------
    ValueError
        Bad shapes or non-finite values, naming the field and row.
    """
    opts = options or CompensateOptions()
    seed = _check_targets(nominal, targets, opts.mode)
    tool = np.asarray(opts.tool_mm, dtype=float)
    flags: list[list[str]] = [[] for _ in range(seed.shape[0])]
    nominal_iterations = np.zeros(seed.shape[0], dtype=int)
    if isinstance(targets, JointTargets):
        q_nom = seed
        target_pos, target_rot = tool_pose(nominal, q_nom, tool)
    else:
        target_pos = np.asarray(targets.position_mm, dtype=float)
        target_rot = None
        if targets.rotation_deg is not None:
            target_rot = Rotation.from_euler(
                EULER_SEQUENCE, targets.rotation_deg, degrees=True
            ).as_matrix()
        pose_rot = target_rot if opts.mode == "pose" else None
        stage = solve_ik(nominal, seed, target_pos, pose_rot, tool, opts.ik)
        q_nom, nominal_iterations = stage.joints_deg, stage.iterations
        for i in np.flatnonzero(~stage.converged):
            flags[i].append("nominal_ik_failed")
        for i in np.flatnonzero(engine.wrist_flipped(seed, q_nom, opts.wrist_flip_min_deg)):
            flags[i].append("nominal_wrist_flip")
    pose_rot = target_rot if opts.mode == "pose" else None
    sol = solve_ik(calibrated, q_nom, target_pos, pose_rot, tool, opts.ik)
    q_cal = sol.joints_deg
    floor_deg, jump_deg = opts.wrist_flip_min_deg, opts.branch_threshold_deg
    jump = engine.left_branch(
        nominal, q_nom, q_cal, jump_deg=jump_deg, wrist_floor_deg=floor_deg, arm_signs=False
    )
    limit_flags = _limit_flags(nominal, q_cal)
    for i in np.flatnonzero(~sol.converged):
        flags[i].append("ik_failed")
    for row, named in zip(flags, limit_flags, strict=True):
        row.extend(named)
    for i in np.flatnonzero(jump):
        flags[i].append("branch_jump")
    uncomp = np.linalg.norm(tool_pose(calibrated, q_nom, tool)[0] - target_pos, axis=1)
    corr_pos, corr_rot = tool_pose(nominal, q_cal, tool)
    result = CompensateResult(
        mode=opts.mode,
        kind="joints" if isinstance(targets, JointTargets) else "cartesian",
        tool_mm=tool,
        nominal_joints_deg=q_nom,
        corrected_joints_deg=q_cal,
        position_residual_mm=sol.position_error_mm,
        rotation_residual_deg=sol.rotation_error_deg,
        iterations=sol.iterations + nominal_iterations,
        uncompensated_error_mm=uncomp,
        corrected_position_mm=corr_pos,
        corrected_rotation_deg=Rotation.from_matrix(corr_rot).as_euler(
            EULER_SEQUENCE, degrees=True
        ),
        flags=flags,
        note=NOTE + (POSE_NOTE if opts.mode == "pose" else ""),
    )
    result.summary = _summary(result)
    return result


def _summary(res: CompensateResult) -> dict[str, Any]:
    counts: dict[str, int] = {}
    for row in res.flags:
        for f in row:
            kind = f.split(":")[0]  # outside_limits:J3=… counts as outside_limits
            counts[kind] = counts.get(kind, 0) + 1
    return {
        "n": len(res.flags),
        "n_flagged": int(np.count_nonzero(~res.ok)),
        "flag_counts": counts,
        "max_residual_mm": float(np.max(res.position_residual_mm)),
        "rms_uncompensated_error_mm": float(np.sqrt(np.mean(res.uncompensated_error_mm**2))),
        "max_correction_deg": float(
            np.max(np.abs(res.corrected_joints_deg - res.nominal_joints_deg))
        ),
        "euler_convention": "fixed-axis X-Y-Z: R = Rz(rz) Ry(ry) Rx(rx)",
    }


def parse_targets_csv(text: str, seed_deg: Sequence[float] | FloatArray | None = None) -> Targets:
    """Targets from CSV text: a header with ``q1..q6`` [deg], or ``x, y, z`` [mm] with
    optional ``rx, ry, rz`` [deg]. Cartesian targets need ``seed_deg`` (shape (6,)).

    Raises
    ------
    ValueError
        Naming the file line (header = 1) and the column.
    """
    reader = csv.reader(io.StringIO(text))
    header = next(reader, None)
    if header is None:
        raise ValueError("line 1: empty file; expected a header with q1..q6 or x, y, z")
    cols = {name.strip().lower(): i for i, name in enumerate(header)}
    if all(c in cols for c in JOINT_COLUMNS):
        names: tuple[str, ...] = JOINT_COLUMNS
    elif all(c in cols for c in POSITION_COLUMNS):
        has_rot = all(c in cols for c in ROTATION_COLUMNS)
        names = POSITION_COLUMNS + (ROTATION_COLUMNS if has_rot else ())
    else:
        raise ValueError(f"line 1: need columns q1..q6 or x, y, z; the header has {header}")
    values: list[list[float]] = []
    for line_no, row in enumerate(reader, start=2):
        if not row or all(not c.strip() for c in row):
            continue
        vals = []
        for name in names:
            cell = row[cols[name]].strip() if cols[name] < len(row) else ""
            try:
                v = float(cell)
            except ValueError:
                raise ValueError(
                    f"line {line_no}, column {name!r}: not a number: {cell!r}"
                ) from None
            if not math.isfinite(v):
                raise ValueError(f"line {line_no}, column {name!r}: not finite: {cell!r}")
            vals.append(v)
        values.append(vals)
    if not values:
        raise ValueError("no data rows after the header")
    data = np.array(values, dtype=float)
    if names == JOINT_COLUMNS:
        return JointTargets(data)
    if seed_deg is None:
        raise ValueError(
            "seed_deg: Cartesian targets need a seed (q1..q6 [deg]) that picks the IK branch"
        )
    return CartesianTargets(
        data[:, :3], data[:, 3:] if data.shape[1] == 6 else None, np.asarray(seed_deg, dtype=float)
    )
