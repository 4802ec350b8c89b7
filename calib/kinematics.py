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

A cable length only needs the Jacobian projected on the cable direction ``u`` (shape (n, 3)).
:func:`projected_jacobian` computes ``uᵀ ∂p/∂θ`` directly with the triple product
``u · (z × (p − o)) = z · ((p − o) × u)``: one cross product for all seven frames and four
dot products, instead of the ``(n, 3, 27)`` array.

**Speed.** Everything is vectorised over poses *and* joints except the chain itself (six
steps). :func:`forward_position` transforms the tool point right to left, ``p = K_1(K_2(…
K_6 t))``, with the elementwise formulas of each ``K_j`` applied to the three coordinate
arrays: about 15 array operations per joint, whatever the batch shape, and no 3×3 or 4×4
products. That makes a call for UKF sigma points (``(2k+1, 6, 4)`` tables) or a DE population
one pass over the data.
"""

from __future__ import annotations

from dataclasses import dataclass
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


def _cross(a: FloatArray, b: FloatArray) -> FloatArray:
    """Cross product over the last axis (size 3) of broadcastable arrays.

    ``np.cross`` moves axes and validates its inputs on every call; on the small stacks of
    this module the explicit formula is several times faster.
    """
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = a1 * b2 - a2 * b1
    out[..., 1] = a2 * b0 - a0 * b2
    out[..., 2] = a0 * b1 - a1 * b0
    return out


@dataclass(frozen=True)
class Chain:
    """One forward pass of :func:`forward_chain`, kept for :func:`projected_jacobian`.

    Attributes
    ----------
    pos_mm : ndarray, shape (..., n, 3)
        Tool point in the base frame [mm].
    inputs : tuple of 6 tuples of 3 ndarrays, each shape (..., n)
        ``inputs[j]``: coordinates of the tool point in the frame *after* joint ``j`` (the
        vector ``K_{j+2} … K_6 t`` that ``K_{j+1}`` acts on) [mm].
    cos_sin_theta : tuple of 6 pairs of ndarrays, each shape (..., n)
        ``cos`` and ``sin`` of ``θ_j + q_j``.
    cos_sin_alpha : tuple of 6 pairs of ndarrays, each shape (..., 1)
    convention : {"dh", "mdh"}
    """

    pos_mm: FloatArray
    inputs: tuple[tuple[FloatArray, FloatArray, FloatArray], ...]
    cos_sin_theta: tuple[tuple[FloatArray, FloatArray], ...]
    cos_sin_alpha: tuple[tuple[FloatArray, FloatArray], ...]
    convention: Convention


#: ``(cos q, sin q)`` of a set of poses, each of shape (6, n) (joint-major): see
#: :func:`joint_trig`.
JointTrig = tuple[FloatArray, FloatArray]


def joint_trig(q_rad: FloatArray) -> JointTrig:
    """``cos`` and ``sin`` of the joint angles ``(n, 6)`` [rad], each shape (6, n).

    Computed once per data set and passed to :func:`forward_chain`, :func:`forward_position`
    and the cable functions, they replace two trigonometric evaluations per joint and call by
    the angle-addition formulas (``cos(θ + q) = cos θ cos q − sin θ sin q``), which matters for
    the UKF, whose sigma points evaluate the same poses with ``2k + 1`` parameter sets.
    """
    q_t = np.asarray(q_rad, dtype=float).T
    return np.ascontiguousarray(np.cos(q_t)), np.ascontiguousarray(np.sin(q_t))


def forward_chain(
    dh: FloatArray,
    q_rad: FloatArray,
    tool_mm: FloatArray,
    convention: Convention = "dh",
    trig: JointTrig | None = None,
) -> Chain:
    """Tool position with the intermediates the projected Jacobian needs.

    Parameters and shapes as :func:`forward_position`; ``trig`` is :func:`joint_trig` of
    ``q_rad``, optional. Returns a :class:`Chain`.

    The point is carried from the flange frame to the base frame one joint at a time
    (``v ← K_j v`` for ``j = 6 … 1``); each ``K_j`` is applied through its closed form on the
    coordinate arrays ``v0, v1, v2`` of shape ``(..., n)``.
    """
    dh = np.asarray(dh, dtype=float)
    q_rad = np.asarray(q_rad, dtype=float)
    tool_mm = np.asarray(tool_mm, dtype=float)
    _check_inputs(dh, q_rad, tool_mm)
    q_joint = np.moveaxis(q_rad, -1, 0)  # (6, n): one joint's angles per row
    # Per-joint constants for all joints at once, each (6, ..., 1): one call per function.
    cols = np.moveaxis(dh, (-2, -1), (0, 1))[..., None]  # (6, 4, ..., 1)
    cos_alpha, sin_alpha = np.cos(cols[:, 0]), np.sin(cols[:, 0])
    a_all, d_all = cols[:, 1], cols[:, 2]
    if trig is not None:
        cos_off, sin_off = np.cos(cols[:, 3]), np.sin(cols[:, 3])
    v0: FloatArray = tool_mm[..., 0, None]  # (..., 1), broadcasts against the poses
    v1: FloatArray = tool_mm[..., 1, None]
    v2: FloatArray = tool_mm[..., 2, None]
    inputs: list[tuple[FloatArray, FloatArray, FloatArray]] = [(v0, v1, v2)] * N_JOINTS
    cs_theta: list[tuple[FloatArray, FloatArray]] = [(v0, v0)] * N_JOINTS
    cs_alpha: list[tuple[FloatArray, FloatArray]] = [(v0, v0)] * N_JOINTS
    for j in range(N_JOINTS - 1, -1, -1):
        inputs[j] = (v0, v1, v2)
        ca, sa = cos_alpha[j], sin_alpha[j]
        if trig is None:
            angle = cols[j, 3] + q_joint[j]
            ct, st = np.cos(angle), np.sin(angle)
        else:
            c_off, s_off = cos_off[j], sin_off[j]
            c_q, s_q = trig[0][j], trig[1][j]
            ct, st = c_off * c_q - s_off * s_q, s_off * c_q + c_off * s_q
        cs_theta[j], cs_alpha[j] = (ct, st), (ca, sa)
        a_col, d_col = a_all[j], d_all[j]
        if convention == "dh":  # Rz(θ) Tz(d) Tx(a) Rx(α) v
            w0 = v0 + a_col
            w1 = ca * v1 - sa * v2
            v2 = sa * v1 + ca * v2 + d_col
            v0 = ct * w0 - st * w1
            v1 = st * w0 + ct * w1
        else:  # Rx(α) Tx(a) Rz(θ) Tz(d) v
            w1 = st * v0 + ct * v1
            w2 = v2 + d_col
            v0 = ct * v0 - st * v1 + a_col
            v1 = ca * w1 - sa * w2
            v2 = sa * w1 + ca * w2
    pos: FloatArray = np.stack(np.broadcast_arrays(v0, v1, v2), axis=-1)
    return Chain(pos, tuple(inputs), tuple(cs_theta), tuple(cs_alpha), convention)


def forward_position(
    dh: FloatArray,
    q_rad: FloatArray,
    tool_mm: FloatArray,
    convention: Convention = "dh",
    trig: JointTrig | None = None,
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
    trig : tuple of 2 ndarrays, shape (6, n), optional
        :func:`joint_trig` of ``q_rad`` (a speed-up when the same poses are evaluated often).

    Returns
    -------
    ndarray, shape (..., n, 3)
        Tool point in the base frame [mm].
    """
    return forward_chain(dh, q_rad, tool_mm, convention, trig).pos_mm


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
    dh = np.asarray(dh, dtype=float)
    q_rad = np.asarray(q_rad, dtype=float)
    n = q_rad.shape[0]
    # All six joint transforms at once: (n, 6, 3, 3) and (n, 6, 3).
    r_all, t_all = _joint_rotation_translation(
        dh[:, 0], dh[:, 1], dh[:, 2], dh[:, 3] + q_rad, convention
    )
    rot = np.empty((n, N_JOINTS + 1, 3, 3))
    origin = np.empty((n, N_JOINTS + 1, 3))
    rot[:, 0] = np.eye(3)
    origin[:, 0] = 0.0
    rot[:, 1] = r_all[:, 0]
    origin[:, 1] = t_all[:, 0]
    for j in range(1, N_JOINTS):
        np.matmul(rot[:, j], t_all[:, j, :, None], out=origin[:, j + 1, :, None])
        origin[:, j + 1] += origin[:, j]
        np.matmul(rot[:, j], r_all[:, j], out=rot[:, j + 1])
    return rot, origin


def tool_position(rot: FloatArray, origin: FloatArray, tool_mm: FloatArray) -> FloatArray:
    """Tool point ``(n, 3)`` [mm] from the frames of :func:`forward_frames`."""
    out: FloatArray = origin[:, N_JOINTS] + rot[:, N_JOINTS] @ np.asarray(tool_mm, dtype=float)
    return out


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
    pos = tool_position(rot, origin, tool_mm)
    n = q_rad.shape[0]
    x_axis, z_axis = rot[..., 0], rot[..., 2]  # (n, 7, 3)
    lever = pos[:, None, :] - origin  # (n, 7, 3)
    cols = np.empty((n, 4 * N_JOINTS + 3, 3))
    block = cols[:, : 4 * N_JOINTS].reshape(n, N_JOINTS, 4, 3)  # a view
    # Classic DH: α and a act about / along x_j, θ and d about / along z_{j-1};
    # modified DH: α and a about / along x_{j-1}, θ and d about / along z_j.
    ax, zx = (
        (slice(1, None), slice(None, -1))
        if convention == "dh"
        else (slice(None, -1), slice(1, None))
    )
    block[:, :, 0] = _cross(x_axis[:, ax], lever[:, ax])
    block[:, :, 1] = x_axis[:, ax]
    block[:, :, 2] = z_axis[:, zx]
    block[:, :, 3] = _cross(z_axis[:, zx], lever[:, zx])
    cols[:, 4 * N_JOINTS :] = np.swapaxes(rot[:, N_JOINTS], -1, -2)
    return pos, np.swapaxes(cols, 1, 2)


def projected_jacobian(chain: Chain, direction: FloatArray) -> FloatArray:
    """``directionᵀ · ∂p/∂(dh, tool)`` per pose, without frames or 3×27 blocks.

    Parameters
    ----------
    chain : Chain
        From :func:`forward_chain` with a single parameter set (``pos_mm`` shape (n, 3)).
    direction : ndarray, shape (n, 3)
        Vector to project on, in the base frame (for a cable length: the unit vector from the
        anchor to ``p``).

    Returns
    -------
    ndarray, shape (n, 27)
        Same column order as :func:`position_jacobian` (angles [mm/rad], lengths [mm/mm] when
        ``direction`` is a unit vector).

    Notes
    -----
    With ``p = A_{j-1} K_j(α, a, d, θ) v_j`` (``A_{j-1}`` the rigid transform of joints
    ``1 … j-1``, ``v_j`` the point in frame ``j``), ``uᵀ ∂p/∂ξ = ũ_{j-1}ᵀ ∂(K_j v_j)/∂ξ`` with
    ``ũ_{j-1} = R_{0,j-1}ᵀ u``, the direction in frame ``j − 1``. A left-to-right pass carries
    ``ũ`` through the elementary rotations (transposed); each joint then contributes four
    scalar expressions. Classic DH, ``K v = Rz(θ) (Rx(α) v + (a, 0, d))``, with
    ``ŭ = Rz(θ)ᵀ ũ`` and ``o = K v``::

        ∂/∂θ = ũ · (e_z × o),  ∂/∂d = ũ_z,  ∂/∂a = ŭ_x,  ∂/∂α = ŭ · (∂Rx/∂α v),  ũ_j = Rx(α)ᵀ ŭ

    Modified DH, ``K v = Rx(α) (Rz(θ)(v + d e_z) + a e_x)``, with ``ŭ = Rx(α)ᵀ ũ`` and
    ``w = Rz(θ)(v + d e_z)``::

        ∂/∂α = ũ · (e_x × o),  ∂/∂a = ũ_x,  ∂/∂d = ŭ_z,  ∂/∂θ = ŭ · (e_z × w),  ũ_j = Rz(θ)ᵀ ŭ

    The tool columns are ``R_06ᵀ u = ũ_6``.
    """
    pos = chain.pos_mm
    if pos.ndim != 2:
        raise ValueError(f"chain: need a single parameter set, got pos_mm shape {pos.shape}")
    n = pos.shape[0]
    u0, u1, u2 = (np.ascontiguousarray(direction[:, i]) for i in range(3))
    out = np.empty((n, 4 * N_JOINTS + 3))
    for j in range(N_JOINTS):
        v0, v1, v2 = chain.inputs[j]
        # o = K_j v_j, the point in frame j − 1: the next joint's input, or p for joint 1.
        o0, o1, o2 = chain.inputs[j - 1] if j else (pos[:, 0], pos[:, 1], pos[:, 2])
        ct, st = chain.cos_sin_theta[j]
        ca, sa = chain.cos_sin_alpha[j]
        c = 4 * j
        if chain.convention == "dh":
            out[:, c + 3] = u1 * o0 - u0 * o1  # ũ · (e_z × o)
            out[:, c + 2] = u2
            b0, b1 = ct * u0 + st * u1, ct * u1 - st * u0  # ŭ = Rz(θ)ᵀ ũ (ŭ_z = ũ_z)
            out[:, c + 1] = b0
            r1, r2 = ca * v1 - sa * v2, sa * v1 + ca * v2  # Rx(α) v; ∂/∂α = (0, −r2, r1)
            out[:, c + 0] = u2 * r1 - b1 * r2
            u0, u1, u2 = b0, ca * b1 + sa * u2, ca * u2 - sa * b1  # ũ_j = Rx(α)ᵀ ŭ
        else:
            out[:, c + 0] = u2 * o1 - u1 * o2  # ũ · (e_x × o)
            out[:, c + 1] = u0
            b1, b2 = ca * u1 + sa * u2, ca * u2 - sa * u1  # ŭ = Rx(α)ᵀ ũ (ŭ_x = ũ_x)
            out[:, c + 2] = b2
            w0, w1 = ct * v0 - st * v1, st * v0 + ct * v1  # Rz(θ) v
            out[:, c + 3] = b1 * w0 - u0 * w1  # ŭ · (e_z × w)
            u0, u1, u2 = ct * u0 + st * b1, ct * b1 - st * u0, b2  # ũ_j = Rz(θ)ᵀ ŭ
    out[:, 4 * N_JOINTS] = u0
    out[:, 4 * N_JOINTS + 1] = u1
    out[:, 4 * N_JOINTS + 2] = u2
    return out
