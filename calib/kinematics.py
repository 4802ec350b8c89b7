"""Forward kinematics and the analytic position Jacobian of a 6R serial robot.

Two conventions are supported:

``"dh"`` (classic Denavit–Hartenberg, the paper's eq. (1))
    ``K_i = Rz(θ_i + q_i) · Tz(d_i) · Tx(a_i) · Rx(α_i)``, so that

    ::

        K_i = [[cθ, -sθ cα,  sθ sα, a cθ],
               [sθ,  cθ cα, -cθ sα, a sθ],
               [ 0,     sα,     cα,    d],
               [ 0,      0,      0,    1]]

``"mdh"`` (modified DH, Craig)
    ``K_i = Rx(α_{i-1}) · Tx(a_{i-1}) · Rz(θ_i + q_i) · Tz(d_i)``. Row ``i`` of a model table
    stores ``(α_{i-1}, a_{i-1}, d_i, θ_i)``, as Craig's tables do.

The point whose position is computed is the cable attachment point ``tool_mm`` given in the
flange (joint-6) frame: ``p = K_1 … K_6 · [tool, 1]``.

Internal units are **millimetres and radians**. Parameter tables have shape ``(..., 6, 4)``
with columns ``(alpha_rad, a_mm, d_mm, theta_rad)``; the leading ``...`` are batch dimensions
over parameter sets (UKF sigma points, DE populations) that broadcast against the poses.

The Jacobian is the closed form from the joint frames (no finite differences). For classic DH,
with ``o_j, x_j, z_j`` the origin and axes of frame ``j`` and ``p`` the tool point:

- ``∂p/∂θ_j = z_{j-1} × (p − o_{j-1})``, ``∂p/∂d_j = z_{j-1}``
- ``∂p/∂a_j = x_j``, ``∂p/∂α_j = x_j × (p − o_j)``

and for modified DH ``∂p/∂α_j = x_{j-1} × (p − o_{j-1})``, ``∂p/∂a_j = x_{j-1}``,
``∂p/∂θ_j = z_j × (p − o_j)``, ``∂p/∂d_j = z_j``. The tool point enters as ``∂p/∂t = R_06``.
"""

from __future__ import annotations

from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

Convention = Literal["dh", "mdh"]
FloatArray = NDArray[np.float64]
#: Integer index arrays (anchor indices, row selections).
IndexArray = NDArray[np.integer[Any]]

N_JOINTS = 6
#: Column order of a parameter table: alpha, a, d, theta.
DH_FIELDS = ("alpha", "a", "d", "theta")


def _joint_rotation_translation(
    alpha: FloatArray, a: FloatArray, d: FloatArray, theta: FloatArray, convention: Convention
) -> tuple[FloatArray, FloatArray]:
    """Rotation ``(..., 3, 3)`` and translation ``(..., 3)`` of one joint transform.

    All inputs broadcast to a common shape ``(...)``; angles in rad, lengths in mm.
    """
    ca, sa = np.cos(alpha), np.sin(alpha)
    ct, st = np.cos(theta), np.sin(theta)
    shape = np.broadcast(ca, ct, a, d).shape
    rot = np.empty((*shape, 3, 3))
    trans = np.empty((*shape, 3))
    if convention == "dh":
        rot[..., 0, 0] = ct
        rot[..., 0, 1] = -st * ca
        rot[..., 0, 2] = st * sa
        rot[..., 1, 0] = st
        rot[..., 1, 1] = ct * ca
        rot[..., 1, 2] = -ct * sa
        rot[..., 2, 0] = 0.0
        rot[..., 2, 1] = sa
        rot[..., 2, 2] = ca
        trans[..., 0] = a * ct
        trans[..., 1] = a * st
        trans[..., 2] = d
    else:  # Rx(alpha) Tx(a) Rz(theta) Tz(d)
        rot[..., 0, 0] = ct
        rot[..., 0, 1] = -st
        rot[..., 0, 2] = 0.0
        rot[..., 1, 0] = st * ca
        rot[..., 1, 1] = ct * ca
        rot[..., 1, 2] = -sa
        rot[..., 2, 0] = st * sa
        rot[..., 2, 1] = ct * sa
        rot[..., 2, 2] = ca
        trans[..., 0] = a
        trans[..., 1] = -sa * d
        trans[..., 2] = ca * d
    return rot, trans


def _check_inputs(dh: FloatArray, q_rad: FloatArray, tool_mm: FloatArray) -> None:
    if dh.shape[-2:] != (N_JOINTS, 4):
        raise ValueError(f"dh must have shape (..., 6, 4), got {dh.shape}")
    if q_rad.ndim < 1 or q_rad.shape[-1] != N_JOINTS:
        raise ValueError(f"q_rad must have shape (..., n, 6), got {q_rad.shape}")
    if tool_mm.shape[-1] != 3:
        raise ValueError(f"tool_mm must have shape (..., 3), got {tool_mm.shape}")


def forward_position(
    dh: FloatArray, q_rad: FloatArray, tool_mm: FloatArray, convention: Convention = "dh"
) -> FloatArray:
    """Position of the tool point for many poses (and optionally many parameter sets).

    Parameters
    ----------
    dh : ndarray, shape (..., 6, 4)
        Per joint ``(alpha_rad, a_mm, d_mm, theta_rad)``; ``theta`` is the joint offset added
        to ``q``.
    q_rad : ndarray, shape (n, 6)
        Joint angles [rad].
    tool_mm : ndarray, shape (..., 3)
        Tool point in the flange frame [mm].
    convention : {"dh", "mdh"}

    Returns
    -------
    ndarray, shape (..., n, 3)
        Tool point in the base frame [mm].
    """
    dh = np.asarray(dh, dtype=float)
    q_rad = np.asarray(q_rad, dtype=float)
    tool_mm = np.asarray(tool_mm, dtype=float)
    _check_inputs(dh, q_rad, tool_mm)
    rot: FloatArray | None = None
    pos: FloatArray | None = None
    for j in range(N_JOINTS):
        alpha = dh[..., j, 0, None]  # (..., 1) broadcasts against the pose axis
        a = dh[..., j, 1, None]
        d = dh[..., j, 2, None]
        theta = dh[..., j, 3, None] + q_rad[..., j]
        r_j, t_j = _joint_rotation_translation(alpha, a, d, theta, convention)
        if rot is None or pos is None:
            rot, pos = r_j, t_j
        else:
            pos = pos + np.einsum("...ij,...j->...i", rot, t_j)
            rot = rot @ r_j
    assert rot is not None and pos is not None
    out: FloatArray = pos + np.einsum("...ij,...j->...i", rot, tool_mm[..., None, :])
    return out


def forward_frames(
    dh: FloatArray, q_rad: FloatArray, convention: Convention = "dh"
) -> tuple[FloatArray, FloatArray]:
    """Rotations and origins of frames 0..6 for a single parameter set.

    Parameters
    ----------
    dh : ndarray, shape (6, 4)
    q_rad : ndarray, shape (n, 6)

    Returns
    -------
    rot : ndarray, shape (n, 7, 3, 3)
        ``rot[:, j]`` is the orientation of frame ``j`` in the base frame (frame 0 = identity).
    origin_mm : ndarray, shape (n, 7, 3)
    """
    n = q_rad.shape[0]
    rot = np.empty((n, N_JOINTS + 1, 3, 3))
    origin = np.empty((n, N_JOINTS + 1, 3))
    rot[:, 0] = np.eye(3)
    origin[:, 0] = 0.0
    for j in range(N_JOINTS):
        r_j, t_j = _joint_rotation_translation(
            dh[j, 0], dh[j, 1], dh[j, 2], dh[j, 3] + q_rad[:, j], convention
        )
        origin[:, j + 1] = origin[:, j] + np.einsum("nij,nj->ni", rot[:, j], t_j)
        rot[:, j + 1] = rot[:, j] @ r_j
    return rot, origin


def position_jacobian(
    dh: FloatArray, q_rad: FloatArray, tool_mm: FloatArray, convention: Convention = "dh"
) -> tuple[FloatArray, FloatArray]:
    """Tool position and its analytic Jacobian with respect to every DH parameter and the tool.

    Parameters
    ----------
    dh : ndarray, shape (6, 4)
        ``(alpha_rad, a_mm, d_mm, theta_rad)`` per joint.
    q_rad : ndarray, shape (n, 6)
    tool_mm : ndarray, shape (3,)

    Returns
    -------
    pos_mm : ndarray, shape (n, 3)
    jac : ndarray, shape (n, 3, 27)
        Columns 0..23 are joint-major ``(alpha [mm/rad], a [mm/mm], d [mm/mm], theta [mm/rad])``,
        columns 24..26 the tool point ``(x, y, z)`` [mm/mm].
    """
    dh = np.asarray(dh, dtype=float)
    q_rad = np.atleast_2d(np.asarray(q_rad, dtype=float))
    tool_mm = np.asarray(tool_mm, dtype=float)
    _check_inputs(dh, q_rad, tool_mm)
    rot, origin = forward_frames(dh, q_rad, convention)
    r6 = rot[:, N_JOINTS]
    pos = origin[:, N_JOINTS] + r6 @ tool_mm
    n = q_rad.shape[0]
    jac = np.empty((n, 3, 4 * N_JOINTS + 3))
    for j in range(N_JOINTS):
        x_prev, z_prev, o_prev = rot[:, j, :, 0], rot[:, j, :, 2], origin[:, j]
        x_this, z_this, o_this = rot[:, j + 1, :, 0], rot[:, j + 1, :, 2], origin[:, j + 1]
        c = 4 * j
        if convention == "dh":
            jac[:, :, c + 0] = np.cross(x_this, pos - o_this)
            jac[:, :, c + 1] = x_this
            jac[:, :, c + 2] = z_prev
            jac[:, :, c + 3] = np.cross(z_prev, pos - o_prev)
        else:
            jac[:, :, c + 0] = np.cross(x_prev, pos - o_prev)
            jac[:, :, c + 1] = x_prev
            jac[:, :, c + 2] = z_this
            jac[:, :, c + 3] = np.cross(z_this, pos - o_this)
    jac[:, :, 24:27] = r6
    return pos, jac
