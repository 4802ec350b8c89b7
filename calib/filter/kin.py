"""The filter's kinematics in the controller's joint angles: its one boundary.

Every joint value in :mod:`calib.filter` (a program's joint target, a nominal solution, the
corrected ``q*``, a joint limit, a UR ``qnear``) is the controller's own, as its pendant shows
it. The kinematic table works on table angles (:mod:`calib.conventions`, the model's
``controller``); the conversion happens here and nowhere else in the filter:
:func:`to_table_deg` on the way into forward or inverse kinematics, :func:`to_controller_deg`
on the way out. The dialects never convert.

The library functions this module calls (:func:`calib.kinematics.forward_frames`,
:func:`calib.ik.solve_ik`) are given :func:`table_model`: the same model with the identity
convention, so they work on table angles whatever they do with a convention themselves.
Shapes: joints (n, 6) [deg], frames (n, 4, 4) [mm].
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from calib.conventions import IDENTITY
from calib.ik import IKOptions, IKSolution, solve_ik
from calib.kinematics import N_JOINTS, FloatArray, forward_frames
from calib.models import RobotModel


def to_table_deg(model: RobotModel, q_ctrl_deg: FloatArray) -> FloatArray:
    """Table angles of the controller's joints (n, 6) [deg] (the way in)."""
    return model.controller.to_table_deg(np.asarray(q_ctrl_deg, dtype=float))


def to_controller_deg(model: RobotModel, q_table_deg: FloatArray) -> FloatArray:
    """The controller's joints of table angles (n, 6) [deg] (the way out)."""
    return model.controller.to_controller_deg(np.asarray(q_table_deg, dtype=float))


def table_model(model: RobotModel) -> RobotModel:
    """``model`` with the identity convention, for library calls on table angles."""
    return model if model.controller.is_identity else replace(model, controller=IDENTITY)


def counted_as(model: RobotModel, like: RobotModel) -> RobotModel:
    """``model`` with ``like``'s convention: one controller counts the joints of the nominal
    and the calibrated model (a result stores no convention)."""
    return replace(model, controller=like.controller)


def drives_no_external_axes(model: RobotModel) -> bool:
    """The model's controller says it drives no external axis (``external_axes = 0``)."""
    return model.controller.external_axes == 0


def whole_turns(model: RobotModel) -> np.ndarray:
    """Per joint (6,) bool: a whole turn of the controller's angle is whole turns of the table
    angles (every coupling factor from it an integer), so ``q ± 360°`` is the same pose."""
    m = model.controller.matrix()
    out: np.ndarray = np.all(np.abs(m - np.round(m)) < 1e-12, axis=0)
    return out


def flange_frames(model: RobotModel, joints_deg: FloatArray) -> FloatArray:
    """Flange frames (n, 4, 4) [mm] of the model at the controller's joints (n, 6) [deg]."""
    q = np.deg2rad(to_table_deg(model, np.asarray(joints_deg, dtype=float)))
    rot, origin = forward_frames(model.dh_internal(), q, model.convention)
    out = np.zeros((q.shape[0], 4, 4))
    out[:, :3, :3] = rot[:, N_JOINTS]
    out[:, :3, 3] = origin[:, N_JOINTS]
    out[:, 3, 3] = 1.0
    return out


def solve_flange_ik(
    model: RobotModel, seed_deg: FloatArray, flange: FloatArray, options: IKOptions
) -> IKSolution:
    """:func:`calib.ik.solve_ik` of flange frames (n, 4, 4) from the controller's seeds
    (n, 6) [deg]; the solution's ``joints_deg`` are the controller's."""
    seed = to_table_deg(model, np.asarray(seed_deg, dtype=float))
    sol = solve_ik(
        table_model(model), seed, flange[:, :3, 3], flange[:, :3, :3], np.zeros(3), options
    )
    return replace(sol, joints_deg=to_controller_deg(model, sol.joints_deg))


def turn_variants(
    base: FloatArray, ok: np.ndarray, limits: FloatArray, near_deg: FloatArray | None
) -> tuple[FloatArray, np.ndarray, int]:
    """Whole-turn variants of base solutions (n, b, 6) [rad] within ``limits`` (6, 2) [rad]:
    candidates (n, b·c, 6), their validity (n, b·c) and c, the variants per base solution
    (candidates are grouped by base solution)."""
    n = base.shape[0]
    two_pi = 2 * np.pi
    k_lo = np.ceil((limits[:, 0] - base) / two_pi - 1e-12)
    k_hi = np.floor((limits[:, 1] - base) / two_pi + 1e-12)
    count = (k_hi - k_lo + 1).astype(int)  # (n, b, 6)
    inside = ok & np.all(count >= 1, axis=2)
    if near_deg is not None:
        near = np.deg2rad(np.asarray(near_deg, dtype=float))[:, None, :]
        has = np.isfinite(near)
        k_near = np.clip(np.round((np.nan_to_num(near) - base) / two_pi), k_lo, k_hi)
        k_use = np.where(has, k_near, k_lo)
        single = base + two_pi * k_use
        multi_joint = np.any((count > 1) & ~has, axis=(0, 1))
        if not np.any(multi_joint):
            return single, inside, 1
    per_joint = [int(min(np.max(np.where(inside, count[..., j], 1)), 3)) for j in range(N_JOINTS)]
    combos = (
        np.array(np.meshgrid(*[np.arange(c) for c in per_joint], indexing="ij"))
        .reshape(N_JOINTS, -1)
        .T
    )  # (c, 6)
    cand = base[:, :, None, :] + two_pi * (k_lo[:, :, None, :] + combos[None, None])
    valid = inside[:, :, None] & np.all(combos[None, None] < count[:, :, None, :], axis=3)
    if near_deg is not None:
        near = np.deg2rad(np.asarray(near_deg, dtype=float))[:, None, None, :]
        has = np.isfinite(near)
        k_near = np.clip(
            np.round((np.nan_to_num(near) - base[:, :, None, :]) / two_pi),
            k_lo[:, :, None, :],
            k_hi[:, :, None, :],
        )
        cand = np.where(has, base[:, :, None, :] + two_pi * k_near, cand)
    return cand.reshape(n, -1, N_JOINTS), valid.reshape(n, -1), combos.shape[0]


__all__ = [
    "counted_as",
    "flange_frames",
    "solve_flange_ik",
    "table_model",
    "to_controller_deg",
    "to_table_deg",
    "turn_variants",
    "whole_turns",
]
