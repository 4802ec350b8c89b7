"""Vectorised damped-least-squares inverse kinematics of a 6R model (positions or poses).

:func:`solve_ik` solves many targets at once: each iteration evaluates the frames of all
still-active targets (:func:`calib.kinematics.forward_frames`), their geometric Jacobian and
one batched linear solve, so a thousand targets cost a few dozen array operations per
iteration instead of a thousand Python loops.

Step: weighted damped least squares,

    ``Δq = W^{-1/2} J̃ᵀ (J̃ J̃ᵀ + λ² I)⁻¹ e``,  ``J̃ = J W^{-1/2}``,

which minimises ``|J Δq − e|² + λ² Σ w_j Δq_j²``: near a singularity the damping ``λ``
[mm/rad] bounds the step; elsewhere it is a Gauss–Newton step with the smallest weighted joint
change (in position mode three degrees of freedom are spare). The damping fades with the
error, ``λ² = damping² · min(1, |e| / 1 mm)`` (in the spirit of Sugihara's Levenberg–Marquardt
IK), so targets near a singularity still converge in a few steps instead of creeping. Each
step is then capped to ``max_step_deg`` on its largest joint.

Rows: the tool point error ``p_target − p`` [mm], and in pose mode the orientation error
``log(R_target Rᵀ)`` (rotation vector, base frame) [rad] times ``rotation_weight_mm_per_rad``.
The geometric Jacobian of a revolute joint with axis ``z`` through ``o`` is
``(z × (p − o), z)``; the axis of joint ``k`` is ``z_{k-1}`` in classic DH and ``z_k`` in
modified DH.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from calib.kinematics import N_JOINTS, FloatArray, forward_frames
from calib.models import RobotModel

#: Relative error decrease that counts as progress for the stall test.
STALL_GAIN = 1e-2
#: Below this weighted error [mm] the damping shrinks in proportion to the error.
DAMPING_FADE_MM = 1.0


@dataclass(frozen=True)
class IKOptions:
    """Options of :func:`solve_ik`.

    Attributes
    ----------
    max_iterations : int
        DLS iterations.
    tol_mm, tol_deg : float
        Convergence: position residual [mm] and (pose mode) orientation residual [deg].
    damping : float
        DLS damping λ [mm/rad]; matters only near singularities.
    max_step_deg : float
        Largest joint change per iteration [deg].
    rotation_weight_mm_per_rad : float
        Weight of the orientation rows in pose mode [mm/rad].
    joint_weights : tuple of 6 floats
        Cost of moving each joint (the step minimises ``Σ w_j Δq_j²``).
    stall_iterations : int
        A target whose weighted error has not dropped by ``STALL_GAIN`` (1 %) below its best
        for this many iterations is given up (near a singularity, or out of reach); its best
        joints are returned.
    """

    max_iterations: int = 100
    tol_mm: float = 1e-6
    tol_deg: float = 1e-6
    damping: float = 1.0
    max_step_deg: float = 5.0
    rotation_weight_mm_per_rad: float = 1000.0
    joint_weights: tuple[float, float, float, float, float, float] = (1.0,) * 6
    stall_iterations: int = 10

    def __post_init__(self) -> None:
        if not (isinstance(self.max_iterations, int) and self.max_iterations >= 1):
            raise ValueError(f"max_iterations must be an integer >= 1, got {self.max_iterations}")
        if not (isinstance(self.stall_iterations, int) and self.stall_iterations >= 1):
            raise ValueError(
                f"stall_iterations must be an integer >= 1, got {self.stall_iterations}"
            )
        for name in ("tol_mm", "tol_deg", "damping", "max_step_deg", "rotation_weight_mm_per_rad"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive number, got {value!r}")
        if len(self.joint_weights) != N_JOINTS or not all(
            math.isfinite(w) and w > 0 for w in self.joint_weights
        ):
            raise ValueError(
                f"joint_weights must be 6 positive numbers, got {self.joint_weights!r}"
            )


@dataclass(frozen=True)
class IKSolution:
    """Result of :func:`solve_ik` for n targets.

    Attributes
    ----------
    joints_deg : ndarray, shape (n, 6)
    iterations : ndarray of int, shape (n,)
    position_error_mm : ndarray, shape (n,)
    rotation_error_deg : ndarray, shape (n,)
        NaN in position mode.
    converged : ndarray of bool, shape (n,)
    """

    joints_deg: FloatArray
    iterations: np.ndarray
    position_error_mm: FloatArray
    rotation_error_deg: FloatArray
    converged: np.ndarray


def tool_pose(
    model: RobotModel, joints_deg: FloatArray, tool_mm: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Tool point ``(n, 3)`` [mm] and flange orientation ``(n, 3, 3)`` of ``model``."""
    rot, origin = forward_frames(model.dh_internal(), model.table_rad(joints_deg), model.convention)
    return origin[:, N_JOINTS] + rot[:, N_JOINTS] @ tool_mm, rot[:, N_JOINTS]


def _joint_axes(model: RobotModel, rot: FloatArray, origin: FloatArray) -> tuple[FloatArray, ...]:
    """Axis ``(n, 6, 3)`` and a point on it ``(n, 6, 3)`` of every joint, base frame."""
    sel = slice(0, N_JOINTS) if model.convention == "dh" else slice(1, N_JOINTS + 1)
    return rot[:, sel, :, 2], origin[:, sel]


def wrist_bend(model: RobotModel, joints_deg: FloatArray) -> FloatArray:
    """Signed sine of the wrist bend, ``(z4 × z6) · z5`` per pose, shape (n,).

    Zero at the wrist singularity (axes 4 and 6 aligned); its sign tells the two wrist
    branches apart (a "wrist flip" changes it).
    """
    rot, origin = forward_frames(model.dh_internal(), model.table_rad(joints_deg), model.convention)
    axes, _ = _joint_axes(model, rot, origin)
    out: FloatArray = np.einsum("ni,ni->n", np.cross(axes[:, 3], axes[:, 5]), axes[:, 4])
    return out


def rotation_vector(rot: FloatArray) -> FloatArray:
    """Rotation vectors ``(n, 3)`` [rad] of rotation matrices ``(n, 3, 3)`` (the log map).

    ``θ = atan2(|v|, (tr R − 1)/2)`` and ``axis = v/|v|`` with ``v = vee(R − Rᵀ)/2``; exact
    for ``θ < π`` and cheaper in the IK loop than scipy's ``Rotation.from_matrix``, which
    re-orthogonalises. Within about 1e-4 rad of ``π`` the axis comes from scipy.
    """
    v = 0.5 * np.stack(
        [rot[:, 2, 1] - rot[:, 1, 2], rot[:, 0, 2] - rot[:, 2, 0], rot[:, 1, 0] - rot[:, 0, 1]],
        axis=1,
    )
    sin = np.linalg.norm(v, axis=1)
    cos = 0.5 * (rot[:, 0, 0] + rot[:, 1, 1] + rot[:, 2, 2] - 1.0)
    angle = np.arctan2(sin, cos)
    factor = np.where(sin > 1e-300, angle / np.maximum(sin, 1e-300), 1.0)
    out: FloatArray = v * factor[:, None]
    near_pi = (sin < 1e-4) & (cos < 0)
    if np.any(near_pi):
        out[near_pi] = Rotation.from_matrix(rot[near_pi]).as_rotvec()
    return out


def _errors_and_jacobian(
    model: RobotModel,
    dh: FloatArray,
    q_rad: FloatArray,
    tool: FloatArray,
    target_pos: FloatArray,
    target_rot: FloatArray | None,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Position error ``(n, 3)`` [mm], rotation error ``(n, 3)`` [rad] (zeros in position
    mode) and the geometric Jacobian ``(n, 3 or 6, 6)`` [mm/rad; rad/rad]."""
    rot, origin = forward_frames(dh, q_rad, model.convention)
    pos = origin[:, N_JOINTS] + rot[:, N_JOINTS] @ tool
    axes, points = _joint_axes(model, rot, origin)
    jac_v = np.cross(axes, pos[:, None, :] - points)  # (n, 6, 3)
    e_pos = target_pos - pos
    if target_rot is None:
        return e_pos, np.zeros_like(e_pos), np.swapaxes(jac_v, 1, 2)
    e_rot = rotation_vector(target_rot @ np.swapaxes(rot[:, N_JOINTS], 1, 2))
    return e_pos, e_rot, np.swapaxes(np.concatenate([jac_v, axes], axis=2), 1, 2)


def solve_ik(
    model: RobotModel,
    seed_deg: FloatArray,
    target_pos_mm: FloatArray,
    target_rot: FloatArray | None,
    tool_mm: FloatArray,
    options: IKOptions,
) -> IKSolution:
    """Damped-least-squares IK for many targets at once.

    Parameters
    ----------
    model : RobotModel
        Kinematics to invert (its ``tool_mm`` is ignored: ``tool_mm`` is the point).
    seed_deg : ndarray, shape (n, 6)
        Start joints [deg].
    target_pos_mm : ndarray, shape (n, 3)
    target_rot : ndarray, shape (n, 3, 3) or None
        Target flange orientations (pose mode) or None (position mode).
    tool_mm : ndarray, shape (3,)
        Tool point in the flange frame [mm].
    options : IKOptions
    """
    dh = model.dh_internal()
    tool = np.asarray(tool_mm, dtype=float)
    q = model.table_rad(np.array(seed_deg, dtype=float))
    n = q.shape[0]
    iterations = np.zeros(n, dtype=int)
    weight = options.rotation_weight_mm_per_rad
    tol_rad = math.radians(options.tol_deg)
    max_step = math.radians(options.max_step_deg)
    scale = 1.0 / np.sqrt(np.asarray(options.joint_weights, dtype=float))
    active = np.arange(n)
    best = np.full(n, np.inf)  # smallest weighted error norm so far, and where
    q_best = q.copy()
    since_best = np.zeros(n, dtype=int)
    for it in range(options.max_iterations + 1):
        rot_t = None if target_rot is None else target_rot[active]
        e_pos, e_rot, jac = _errors_and_jacobian(
            model, dh, q[active], tool, target_pos_mm[active], rot_t
        )
        err = e_pos if target_rot is None else np.concatenate([e_pos, weight * e_rot], axis=1)
        norm = np.linalg.norm(err, axis=1)
        improved = norm < (1.0 - STALL_GAIN) * best[active]
        rows = active[improved]
        best[rows], q_best[rows], since_best[rows] = norm[improved], q[rows], 0
        since_best[active[~improved]] += 1
        ok = (np.linalg.norm(e_pos, axis=1) <= options.tol_mm) & (
            np.linalg.norm(e_rot, axis=1) <= tol_rad
        )
        q_best[active[ok]] = q[active[ok]]
        keep = ~ok & (since_best[active] < options.stall_iterations)
        active, err, jac = active[keep], err[keep], jac[keep]
        if active.size == 0 or it == options.max_iterations:
            break
        if target_rot is not None:
            jac = jac.copy()
            jac[:, 3:] *= weight
        jac = jac * scale  # weighted DLS: minimise Σ w_j Δq_j², i.e. solve for Δq √w
        # Damping fades with the error (as in Sugihara's LM IK): robust far away, Gauss–Newton
        # (fast) close to the solution, even near a singularity.
        lam2 = options.damping**2 * np.minimum(1.0, norm[keep] / DAMPING_FADE_MM)
        gram = jac @ np.swapaxes(jac, 1, 2) + lam2[:, None, None] * np.eye(err.shape[1])
        dq = np.einsum("nmj,nm->nj", jac, np.linalg.solve(gram, err[..., None])[..., 0])
        dq *= scale
        biggest = np.max(np.abs(dq), axis=1)
        dq *= np.minimum(1.0, max_step / np.maximum(biggest, 1e-300))[:, None]
        q[active] += dq
        iterations[active] += 1
    q = q_best
    e_pos, e_rot, _ = _errors_and_jacobian(model, dh, q, tool, target_pos_mm, target_rot)
    pos_err = np.linalg.norm(e_pos, axis=1)
    rot_err = (
        np.full(n, np.nan) if target_rot is None else np.rad2deg(np.linalg.norm(e_rot, axis=1))
    )
    converged = (pos_err <= options.tol_mm) & (np.nan_to_num(rot_err) <= options.tol_deg)
    return IKSolution(model.controller_deg(q), iterations, pos_err, rot_err, converged)
