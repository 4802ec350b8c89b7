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

import math
from collections.abc import Sequence

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
    if q.shape == (4,):  # one quaternion: plain floats are far cheaper than array calls
        w, x, y, z = (float(v) for v in q)
        n = math.sqrt(w * w + x * x + y * y + z * z)
        if n < 1e-6:
            raise ValueError("quaternion of zero norm")
        w, x, y, z = w / n, x / n, y / n, z / n
        return np.array(
            [
                [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
            ]
        )
    norm = np.linalg.norm(q, axis=-1)
    if np.any(norm < 1e-6):
        raise ValueError("quaternion of zero norm")
    w, x, y, z = np.moveaxis(q / norm[..., None], -1, 0)
    out = np.empty((*q.shape[:-1], 3, 3))
    out[..., 0, 0] = 1 - 2 * (y * y + z * z)
    out[..., 0, 1] = 2 * (x * y - w * z)
    out[..., 0, 2] = 2 * (x * z + w * y)
    out[..., 1, 0] = 2 * (x * y + w * z)
    out[..., 1, 1] = 1 - 2 * (x * x + z * z)
    out[..., 1, 2] = 2 * (y * z - w * x)
    out[..., 2, 0] = 2 * (x * z - w * y)
    out[..., 2, 1] = 2 * (y * z + w * x)
    out[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return out


def matrix_to_quat_wxyz(rot: FloatArray, near: FloatArray | None = None) -> FloatArray:
    """Unit quaternions ``(w, x, y, z)`` (…, 4) of rotations (…, 3, 3) (Shepperd's method:
    from the largest of ``w², x², y², z²``, well conditioned everywhere); with ``near``
    (…, 4), each sign is chosen to be closest to it (``q`` and ``-q`` are the same rotation),
    so a target keeps the sign its program had."""
    r = np.asarray(rot, dtype=float)
    if r.shape == (3, 3):
        return _quat_one(r, None if near is None else np.asarray(near, dtype=float))
    m00, m11, m22 = r[..., 0, 0], r[..., 1, 1], r[..., 2, 2]
    cand = np.stack(
        [1 + m00 + m11 + m22, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22],
        axis=-1,
    )  # 4w², 4x², 4y², 4z²
    k = np.argmax(cand, axis=-1)
    s = 2.0 * np.sqrt(np.maximum(np.take_along_axis(cand, k[..., None], -1)[..., 0], 1e-300))
    d21, d02, d10 = (
        r[..., 2, 1] - r[..., 1, 2],
        r[..., 0, 2] - r[..., 2, 0],
        r[..., 1, 0] - r[..., 0, 1],
    )
    a01, a02, a12 = (
        r[..., 0, 1] + r[..., 1, 0],
        r[..., 0, 2] + r[..., 2, 0],
        r[..., 1, 2] + r[..., 2, 1],
    )
    rows = [
        np.stack([s / 4, d21 / s, d02 / s, d10 / s], -1),
        np.stack([d21 / s, s / 4, a01 / s, a02 / s], -1),
        np.stack([d02 / s, a01 / s, s / 4, a12 / s], -1),
        np.stack([d10 / s, a02 / s, a12 / s, s / 4], -1),
    ]
    out: FloatArray = np.choose(k[..., None], rows)
    out = out / np.linalg.norm(out, axis=-1, keepdims=True)
    if near is not None:
        flip = np.einsum("...i,...i->...", out, np.asarray(near, dtype=float)) < 0
        out = np.where(flip[..., None], -out, out)
    elif np.ndim(out) >= 1:
        out = np.where((out[..., :1] < 0), -out, out)  # w >= 0 by default
    return out


def _quat_one(r: FloatArray, near: FloatArray | None) -> FloatArray:
    """:func:`matrix_to_quat_wxyz` of one matrix, in plain floats."""
    (m00, m01, m02), (m10, m11, m12), (m20, m21, m22) = r.tolist()
    cand = (1 + m00 + m11 + m22, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22)
    k = max(range(4), key=cand.__getitem__)
    s = 2.0 * math.sqrt(max(cand[k], 1e-300))
    d21, d02, d10 = m21 - m12, m02 - m20, m10 - m01
    a01, a02, a12 = m01 + m10, m02 + m20, m12 + m21
    q = (
        (s / 4, d21 / s, d02 / s, d10 / s),
        (d21 / s, s / 4, a01 / s, a02 / s),
        (d02 / s, a01 / s, s / 4, a12 / s),
        (d10 / s, a02 / s, a12 / s, s / 4),
    )[k]
    n = math.sqrt(sum(v * v for v in q))
    sign = 1.0
    if near is not None:
        sign = -1.0 if sum(a * b for a, b in zip(q, near.tolist(), strict=True)) < 0 else 1.0
    elif q[0] < 0:
        sign = -1.0
    return np.array([sign * v / n for v in q])


def zyx_deg_to_matrix(
    a_deg: FloatArray | float, b_deg: FloatArray | float, c_deg: FloatArray | float
) -> FloatArray:
    """``Rz(a) · Ry(b) · Rx(c)`` (angles [deg], broadcastable) as (…, 3, 3): KUKA ``A, B, C``;
    Fanuc ``W, P, R`` is ``zyx_deg_to_matrix(R, P, W)``. Closed form (scipy's ``from_euler``
    costs ~0.3 ms a call, and a dialect reads one target a call); one angle triple of plain
    numbers goes through the math module."""
    if all(isinstance(v, float | int) or np.ndim(v) == 0 for v in (a_deg, b_deg, c_deg)):
        sa, ca = math.sin(math.radians(float(a_deg))), math.cos(math.radians(float(a_deg)))
        sb, cb = math.sin(math.radians(float(b_deg))), math.cos(math.radians(float(b_deg)))
        sc, cc = math.sin(math.radians(float(c_deg))), math.cos(math.radians(float(c_deg)))
        return np.array(
            [
                [ca * cb, ca * sb * sc - sa * cc, ca * sb * cc + sa * sc],
                [sa * cb, sa * sb * sc + ca * cc, sa * sb * cc - ca * sc],
                [-sb, cb * sc, cb * cc],
            ]
        )
    a, b, c = np.broadcast_arrays(
        *(np.deg2rad(np.asarray(v, dtype=float)) for v in (a_deg, b_deg, c_deg))
    )
    sa, ca, sb, cb, sc, cc = np.sin(a), np.cos(a), np.sin(b), np.cos(b), np.sin(c), np.cos(c)
    out: FloatArray = np.empty((*a.shape, 3, 3))
    out[..., 0, 0] = ca * cb
    out[..., 0, 1] = ca * sb * sc - sa * cc
    out[..., 0, 2] = ca * sb * cc + sa * sc
    out[..., 1, 0] = sa * cb
    out[..., 1, 1] = sa * sb * sc + ca * cc
    out[..., 1, 2] = sa * sb * cc - ca * sc
    out[..., 2, 0] = -sb
    out[..., 2, 1] = cb * sc
    out[..., 2, 2] = cb * cc
    return out


def matrix_to_zyx_deg(
    rot: FloatArray, near_deg: FloatArray | Sequence[float] | None = None
) -> FloatArray:
    """``(a, b, c)`` [deg] (…, 3) with ``R = Rz(a) · Ry(b) · Rx(c)``; ``b`` in [-90, 90].

    With ``near_deg`` (…, 3), each angle is moved by whole turns to lie closest to it, so a
    target written as ``C = -180`` stays near ``-180`` rather than jumping to ``+180``.
    """
    rot = np.asarray(rot, dtype=float)
    # Closed form (scipy's from_matrix costs ~0.2 ms a call; a filter renders one target a
    # call): R[1,0] = sa cb, R[0,0] = ca cb, R[2,0] = -sb, R[2,1] = cb sc, R[2,2] = cb cc.
    # At B = ±90 deg only A ∓ C is defined: A is set to 0.
    if rot.shape == (3, 3) and (near_deg is None or np.shape(near_deg) == (3,)):
        return np.array(_zyx_deg_one(rot.tolist(), near_deg))
    r00, r10, r20 = rot[..., 0, 0], rot[..., 1, 0], rot[..., 2, 0]
    cb = np.hypot(r00, r10)
    lock = cb < 1e-9
    a = np.where(lock, 0.0, np.arctan2(r10, r00))
    c_lock = np.where(
        r20 < 0,
        np.arctan2(rot[..., 0, 1], rot[..., 0, 2]),
        np.arctan2(-rot[..., 0, 1], -rot[..., 0, 2]),
    )
    c = np.where(lock, c_lock, np.arctan2(rot[..., 2, 1], rot[..., 2, 2]))
    out: FloatArray = np.degrees(np.stack([a, np.arctan2(-r20, cb), c], axis=-1))
    if near_deg is not None:
        near = np.asarray(near_deg, dtype=float)
        out = out + 360.0 * np.round((near - out) / 360.0)
    return out


def _zyx_deg_one(
    r: list[list[float]], near_deg: FloatArray | Sequence[float] | None
) -> list[float]:
    """:func:`matrix_to_zyx_deg` of one rotation (nested lists) with the math module: the
    same formulas, without numpy's per-call cost (a dialect renders one target a call)."""
    cb = math.hypot(r[0][0], r[1][0])
    if cb < 1e-9:
        a = 0.0
        sign = 1.0 if r[2][0] < 0 else -1.0
        c = math.atan2(sign * r[0][1], sign * r[0][2])
    else:
        a = math.atan2(r[1][0], r[0][0])
        c = math.atan2(r[2][1], r[2][2])
    out = [math.degrees(a), math.degrees(math.atan2(-r[2][0], cb)), math.degrees(c)]
    if near_deg is not None:
        near = [float(v) for v in near_deg]
        out = [v + 360.0 * round((n - v) / 360.0) for v, n in zip(out, near, strict=True)]
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
    if rot.shape == (3, 3):  # one target (a dialect's render): no scipy call per target
        out: FloatArray = np.array(_rotvec_one(rot.tolist()))
    else:
        out = Rotation.from_matrix(rot.reshape(-1, 3, 3)).as_rotvec()
        out = out.reshape(*rot.shape[:-2], 3)
    if near is not None:
        ang = np.linalg.norm(out, axis=-1, keepdims=True)
        alt = np.where(ang > 1e-9, out * (1.0 - 2.0 * np.pi / np.maximum(ang, 1e-12)), out)
        near = np.asarray(near, dtype=float)
        use_alt = np.linalg.norm(alt - near, axis=-1) < np.linalg.norm(out - near, axis=-1)
        out = np.where(use_alt[..., None], alt, out)
    return out


def _rotvec_one(r: list[list[float]]) -> list[float]:
    """The rotation vector of one rotation matrix: its unit quaternion by Shepperd's method
    (from the largest of ``w, x, y, z``, so no division by a small number), ``w ≥ 0``, then
    ``angle = 2 atan2(|xyz|, w)`` in [0, π]."""
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = r
    tr = r00 + r11 + r22
    big = max(tr, r00, r11, r22)
    if big == tr:
        w = 0.5 * math.sqrt(max(1.0 + tr, 0.0))
        x, y, z = (r21 - r12) / (4 * w), (r02 - r20) / (4 * w), (r10 - r01) / (4 * w)
    elif big == r00:
        x = 0.5 * math.sqrt(max(1.0 + r00 - r11 - r22, 0.0))
        w, y, z = (r21 - r12) / (4 * x), (r01 + r10) / (4 * x), (r02 + r20) / (4 * x)
    elif big == r11:
        y = 0.5 * math.sqrt(max(1.0 - r00 + r11 - r22, 0.0))
        w, x, z = (r02 - r20) / (4 * y), (r01 + r10) / (4 * y), (r12 + r21) / (4 * y)
    else:
        z = 0.5 * math.sqrt(max(1.0 - r00 - r11 + r22, 0.0))
        w, x, y = (r10 - r01) / (4 * z), (r02 + r20) / (4 * z), (r12 + r21) / (4 * z)
    if w < 0:
        w, x, y, z = -w, -x, -y, -z
    n = math.sqrt(x * x + y * y + z * z)
    norm = math.sqrt(w * w + n * n)
    factor = 2.0 * math.atan2(n, w) / n if n > 1e-300 else 2.0 / norm
    return [x * factor, y * factor, z * factor]


def rotation_angle_deg(a: FloatArray, b: FloatArray) -> FloatArray:
    """Angle [deg] of ``aᵀ b`` for rotations (…, 3, 3): how far ``b`` is turned from ``a``."""
    if np.shape(a) == (3, 3) and np.shape(b) == (3, 3):
        rel1 = np.asarray(a).T @ np.asarray(b)
        c = max(-1.0, min(1.0, (float(np.trace(rel1)) - 1.0) / 2.0))
        sk = (rel1[2, 1] - rel1[1, 2], rel1[0, 2] - rel1[2, 0], rel1[1, 0] - rel1[0, 1])
        return np.float64(math.degrees(math.atan2(0.5 * math.sqrt(sum(v * v for v in sk)), c)))  # type: ignore[return-value]
    rel = np.einsum("...ji,...jk->...ik", a, b)
    cos = np.clip((np.trace(rel, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    # arccos loses precision near 0: use the skew part there.
    skew = 0.5 * np.stack(
        [
            rel[..., 2, 1] - rel[..., 1, 2],
            rel[..., 0, 2] - rel[..., 2, 0],
            rel[..., 1, 0] - rel[..., 0, 1],
        ],
        axis=-1,
    )
    out: FloatArray = np.degrees(np.arctan2(np.linalg.norm(skew, axis=-1), cos))
    return out
