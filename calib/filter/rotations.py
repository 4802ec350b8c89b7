"""Rotation conventions of the four controllers and 4x4 frames (pure numpy/scipy).

Frames are homogeneous transforms, shape (4, 4) (or (n, 4, 4)), translation in **mm**.
Conventions, exactly:

* RAPID quaternion ``[q1, q2, q3, q4] = w, x, y, z`` (scalar first), normalised on output;
* KUKA ``A, B, C``: ``R = Rz(A) · Ry(B) · Rx(C)`` [deg];
* Fanuc ``W, P, R``: ``R = Rz(R) · Ry(P) · Rx(W)`` [deg] (the same matrix as KUKA's with
  ``A = R, B = P, C = W``);
* UR: a rotation vector ``(rx, ry, rz)`` [rad] (axis times angle), positions in metres.

``Rz(a) · Ry(b) · Rx(c)`` is scipy's extrinsic ``"xyz"`` sequence with angles ``(c, b, a)``.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from calib.kinematics import FloatArray


def frame(position_mm: FloatArray, rotation: FloatArray) -> FloatArray:
    """A 4x4 frame from a position (3,) [mm] and a rotation matrix (3, 3)."""
    out = np.eye(4)
    out[:3, :3] = rotation
    out[:3, 3] = position_mm
    return out


def frames(position_mm: FloatArray, rotation: FloatArray) -> FloatArray:
    """Frames (n, 4, 4) from positions (n, 3) [mm] and rotations (n, 3, 3)."""
    n = position_mm.shape[0]
    out = np.zeros((n, 4, 4))
    out[:, :3, :3] = rotation
    out[:, :3, 3] = position_mm
    out[:, 3, 3] = 1.0
    return out


def invert(f: FloatArray) -> FloatArray:
    """Inverse of a rigid frame (…, 4, 4) without a general matrix inverse."""
    out = np.zeros_like(f)
    rt = np.swapaxes(f[..., :3, :3], -1, -2)
    out[..., :3, :3] = rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", rt, f[..., :3, 3])
    out[..., 3, 3] = 1.0
    return out


def quat_wxyz_to_matrix(q: FloatArray) -> FloatArray:
    """RAPID quaternion(s) ``(w, x, y, z)`` (…, 4) to rotation matrices (…, 3, 3); normalised
    first (a program's quaternion is rarely of unit norm to the last digit).

    Raises
    ------
    ValueError
        A quaternion of (near) zero norm.
    """
    q = np.asarray(q, dtype=float)
    norm = np.linalg.norm(q, axis=-1)
    if np.any(norm < 1e-6):
        raise ValueError("quaternion of zero norm")
    xyzw = np.concatenate([q[..., 1:], q[..., :1]], axis=-1)
    out: FloatArray = Rotation.from_quat(xyzw.reshape(-1, 4)).as_matrix()
    return out.reshape(*q.shape[:-1], 3, 3)


def matrix_to_quat_wxyz(rot: FloatArray, near: FloatArray | None = None) -> FloatArray:
    """Unit quaternions ``(w, x, y, z)`` (…, 4) of rotations (…, 3, 3); with ``near`` (…, 4),
    each sign is chosen to be closest to it (``q`` and ``-q`` are the same rotation), so a
    target keeps the sign its program had."""
    rot = np.asarray(rot, dtype=float)
    xyzw = Rotation.from_matrix(rot.reshape(-1, 3, 3)).as_quat()
    out: FloatArray = np.concatenate([xyzw[:, 3:], xyzw[:, :3]], axis=1).reshape(*rot.shape[:-2], 4)
    if near is not None:
        flip = np.einsum("...i,...i->...", out, np.asarray(near, dtype=float)) < 0
        out = np.where(flip[..., None], -out, out)
    return out


def zyx_deg_to_matrix(
    a_deg: FloatArray | float, b_deg: FloatArray | float, c_deg: FloatArray | float
) -> FloatArray:
    """``Rz(a) · Ry(b) · Rx(c)`` (angles [deg], broadcastable) as (…, 3, 3): KUKA ``A, B, C``;
    Fanuc ``W, P, R`` is ``zyx_deg_to_matrix(R, P, W)``."""
    a, b, c = np.broadcast_arrays(*(np.asarray(v, dtype=float) for v in (a_deg, b_deg, c_deg)))
    angles = np.stack([c, b, a], axis=-1).reshape(-1, 3)
    out: FloatArray = Rotation.from_euler("xyz", angles, degrees=True).as_matrix()
    return out.reshape(*a.shape, 3, 3)


def matrix_to_zyx_deg(rot: FloatArray, near_deg: FloatArray | None = None) -> FloatArray:
    """``(a, b, c)`` [deg] (…, 3) with ``R = Rz(a) · Ry(b) · Rx(c)``; ``b`` in [-90, 90].

    With ``near_deg`` (…, 3), each angle is moved by whole turns to lie closest to it, so a
    target written as ``C = -180`` stays near ``-180`` rather than jumping to ``+180``.
    """
    rot = np.asarray(rot, dtype=float)
    # Closed form (scipy's from_matrix costs ~0.2 ms a call; a filter renders one target a
    # call): R[1,0] = sa cb, R[0,0] = ca cb, R[2,0] = -sb, R[2,1] = cb sc, R[2,2] = cb cc.
    # At B = ±90 deg only A ∓ C is defined: A is set to 0.
    r00, r10, r20 = rot[..., 0, 0], rot[..., 1, 0], rot[..., 2, 0]
    cb = np.hypot(r00, r10)
    lock = cb < 1e-9
    a = np.where(lock, 0.0, np.arctan2(r10, r00))
    c_lock = np.where(r20 < 0, np.arctan2(rot[..., 0, 1], rot[..., 0, 2]),
                      np.arctan2(-rot[..., 0, 1], -rot[..., 0, 2]))  # fmt: skip
    c = np.where(lock, c_lock, np.arctan2(rot[..., 2, 1], rot[..., 2, 2]))
    out: FloatArray = np.degrees(np.stack([a, np.arctan2(-r20, cb), c], axis=-1))
    if near_deg is not None:
        near = np.asarray(near_deg, dtype=float)
        out = out + 360.0 * np.round((near - out) / 360.0)
    return out


def rotvec_to_matrix(rotvec_rad: FloatArray) -> FloatArray:
    """UR rotation vectors (…, 3) [rad] to rotation matrices (…, 3, 3)."""
    v = np.asarray(rotvec_rad, dtype=float)
    out: FloatArray = Rotation.from_rotvec(v.reshape(-1, 3)).as_matrix()
    return out.reshape(*v.shape[:-1], 3, 3)


def matrix_to_rotvec(rot: FloatArray, near: FloatArray | None = None) -> FloatArray:
    """Rotation vectors (…, 3) [rad], angle in [0, π]; with ``near`` (…, 3), the equivalent
    vector ``v (1 − 2π/|v|)`` is taken when it lies closer to ``near`` (a pose near a half
    turn may be written either way)."""
    rot = np.asarray(rot, dtype=float)
    out: FloatArray = Rotation.from_matrix(rot.reshape(-1, 3, 3)).as_rotvec()
    out = out.reshape(*rot.shape[:-2], 3)
    if near is not None:
        ang = np.linalg.norm(out, axis=-1, keepdims=True)
        alt = np.where(ang > 1e-9, out * (1.0 - 2.0 * np.pi / np.maximum(ang, 1e-12)), out)
        near = np.asarray(near, dtype=float)
        use_alt = np.linalg.norm(alt - near, axis=-1) < np.linalg.norm(out - near, axis=-1)
        out = np.where(use_alt[..., None], alt, out)
    return out


def rotation_angle_deg(a: FloatArray, b: FloatArray) -> FloatArray:
    """Angle [deg] of ``aᵀ b`` for rotations (…, 3, 3): how far ``b`` is turned from ``a``."""
    rel = np.einsum("...ji,...jk->...ik", a, b)
    cos = np.clip((np.trace(rel, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    # arccos loses precision near 0: use the skew part there.
    skew = 0.5 * np.stack([rel[..., 2, 1] - rel[..., 1, 2], rel[..., 0, 2] - rel[..., 2, 0],
                           rel[..., 1, 0] - rel[..., 0, 1]], axis=-1)  # fmt: skip
    out: FloatArray = np.degrees(np.arctan2(np.linalg.norm(skew, axis=-1), cos))
    return out
