"""Every nominal IK solution of a Cartesian target, and the branch a controller takes.

A controller turns a Cartesian target into joints with its nominal model, on the branch its
configuration fields name. To correct a target on that branch the filter needs the nominal
solution itself: :func:`nominal_solutions` finds all of them at once for many targets (in the
controller's joint angles, :mod:`calib.filter.kin`), and :func:`calib.filter.select.choose`
picks the controller's. A UR's offset wrist has its own closed form
(:mod:`calib.filter.ur_ik`); the rest of this module solves a **spherical wrist** (axes 4, 5,
6 meet in one point, the wrist centre ``c``; checked numerically per model by
:func:`wrist_geometry`). The chain is ``T = G_0 Rz(q_1) G_1 Rz(q_2) … Rz(q_6) G_6`` with
fixed ``G_k`` (classic DH: ``G_0 = I``, ``G_k = Rz(θ_k) Tz(d_k) Tx(a_k) Rx(α_k)``; modified
DH: ``G_0 = D_1``, ``G_k = Tz(d_k) D_{k+1}``, ``G_6 = Tz(d_6)``, ``D_k = Rx(α_{k-1})
Tx(a_{k-1}) Rz(θ_k)``); angles here are the table's.

1. The arm (q1..q3) places ``c``: damped Newton on the three joints from four seeds per
   target, the two shoulder sides (``q1`` towards ``c`` and opposite) times the two elbow
   sides (``q3`` a quarter turn either side of the stretched arm), ``q2`` aimed at ``c``
   by the rotation about axis 2 that brings the seed's ``c`` closest (duplicates merged).
2. The wrist (q4..q6) in closed form: with ``M = (G_0 Rz(q_1) … G_3)ᵀ R G_6ᵀ =
   Rz(q_4) A Rz(q_5) B Rz(q_6)`` (``A, B`` the rotations of ``G_4, G_5``),
   ``e_zᵀ M e_z = (Aᵀe_z)ᵀ Rz(q_5) (B e_z)`` gives the two ``q_5``; ``q_4`` and ``q_6``
   follow from ``M e_z`` and ``e_zᵀ M``. At the wrist singularity ``q_4`` is set to 0.
3. Whole turns: :func:`calib.filter.kin.turn_variants`.

Checks (else dropped): wrist centre within :data:`ARM_TOL_MM`, rotation 10 × :data:`CHECK_TOL_RAD`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from calib.filter.kin import (
    flange_frames,
    to_controller_deg,
    to_table_deg,
    turn_variants,
    whole_turns,
)
from calib.filter.ur_ik import ORDER, ur_shape, ur_signs, ur_solutions
from calib.filter.ur_ik import rz3 as _rz3
from calib.kinematics import N_JOINTS, FloatArray, forward_frames
from calib.models import RobotModel
from calib.tcp import joint_limits_deg

#: Tolerances of a nominal solution: the wrist centre [mm], the wrist's orientation [rad].
ARM_TOL_MM = 1e-7
CHECK_TOL_RAD = 1e-7
ARM_ITERATIONS = 25


def _rz(q: FloatArray) -> FloatArray:
    """Homogeneous rotations about z, (…, 4, 4), for angles (…) [rad]."""
    c, s = np.cos(q), np.sin(q)
    out = np.zeros((*np.shape(q), 4, 4))
    out[..., 0, 0] = c
    out[..., 0, 1] = -s
    out[..., 1, 0] = s
    out[..., 1, 1] = c
    out[..., 2, 2] = 1.0
    out[..., 3, 3] = 1.0
    return out


def _tz(d: float) -> FloatArray:
    out = np.eye(4)
    out[2, 3] = d
    return out


def _tx(a: float) -> FloatArray:
    out = np.eye(4)
    out[0, 3] = a
    return out


def _rx(alpha: float) -> FloatArray:
    c, s = math.cos(alpha), math.sin(alpha)
    out = np.eye(4)
    out[1, 1], out[1, 2], out[2, 1], out[2, 2] = c, -s, s, c
    return out


def fixed_transforms(model: RobotModel) -> list[FloatArray]:
    """``G_0 … G_6`` (each (4, 4)) of the module docstring."""
    dh = model.dh_internal()  # alpha, a, d, theta per joint
    if model.convention == "dh":
        out = [np.eye(4)]
        for alpha, a, d, theta in dh:
            out.append(_rz(np.asarray(theta)) @ _tz(d) @ _tx(a) @ _rx(alpha))
        return out

    def big_d(k: int) -> FloatArray:  # D_k, 0-based joint k
        alpha, a, _d, theta = dh[k]
        return _rx(alpha) @ _tx(a) @ _rz(np.asarray(theta))

    out = [big_d(0)]
    for k in range(N_JOINTS - 1):
        out.append(_tz(dh[k, 2]) @ big_d(k + 1))
    out.append(_tz(dh[N_JOINTS - 1, 2]))
    return out


def chain(g: list[FloatArray], q_rad: FloatArray, upto: int = N_JOINTS) -> FloatArray:
    """``G_0 Rz(q_1) G_1 … Rz(q_upto) G_upto`` for joints (n, ≥upto) [rad], shape (n, 4, 4)."""
    n = q_rad.shape[0]
    out = np.broadcast_to(g[0], (n, 4, 4)).copy()
    for k in range(upto):
        out = out @ _rz(q_rad[:, k]) @ g[k + 1]
    return out


@dataclass(frozen=True)
class WristGeometry:
    """What the closed-form wrist needs of a model.

    Attributes
    ----------
    g : list of 7 ndarrays (4, 4)
    centre_arm : ndarray (4,)
        The wrist centre in the frame ``G_0 Rz(q_1) … Rz(q_3)`` (homogeneous), before ``G_3``.
    centre_flange : ndarray (3,)
        The wrist centre in the flange frame [mm].
    q3_stretched_rad : float
        ``q3`` where the wrist centre is farthest from axis 2 (the arm stretched).
    forward_azimuth_rad : float
        Azimuth of frame 1's x axis at ``q1 = 0`` (the arm's "front").
    """

    g: list[FloatArray]
    centre_arm: FloatArray
    centre_flange: FloatArray
    q3_stretched_rad: float
    forward_azimuth_rad: float


def _axes(model: RobotModel, rot: FloatArray, origin: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Joint axis directions (n, 6, 3) and points on them (n, 6, 3)."""
    sel = slice(0, N_JOINTS) if model.convention == "dh" else slice(1, N_JOINTS + 1)
    return rot[:, sel, :, 2], origin[:, sel]


@lru_cache(maxsize=16)
def _geometry_cached(key: tuple[str, bytes]) -> WristGeometry | None:
    convention, raw = key
    table = np.frombuffer(raw, dtype=float).reshape(N_JOINTS, 4)
    model = RobotModel("cache", convention, table)  # type: ignore[arg-type]
    return _geometry(model)


def wrist_geometry(model: RobotModel) -> WristGeometry | None:
    """The wrist geometry of ``model``, or None when its wrist is not spherical."""
    key = (model.convention, np.ascontiguousarray(model.dh_table, dtype=float).tobytes())
    return _geometry_cached(key)


def _geometry(model: RobotModel) -> WristGeometry | None:
    g = fixed_transforms(model)
    rng = np.random.default_rng(7)
    q = rng.uniform(-np.pi, np.pi, size=(3, N_JOINTS))
    rot, origin = forward_frames(model.dh_internal(), q, model.convention)
    # The chain must reproduce forward_frames' flange.
    flange = chain(g, q)
    if not (
        np.allclose(flange[:, :3, :3], rot[:, N_JOINTS], atol=1e-9)
        and np.allclose(flange[:, :3, 3], origin[:, N_JOINTS], atol=1e-6)
    ):
        raise AssertionError("fixed_transforms disagrees with calib.kinematics")
    axes, points = _axes(model, rot, origin)
    centres = []
    for i in range(q.shape[0]):
        # Least-squares point closest to the axes 4, 5, 6.
        lhs, rhs = np.zeros((3, 3)), np.zeros(3)
        for k in (3, 4, 5):
            proj = np.eye(3) - np.outer(axes[i, k], axes[i, k])
            lhs += proj
            rhs += proj @ points[i, k]
        c = np.linalg.lstsq(lhs, rhs, rcond=None)[0]
        for k in (3, 4, 5):
            d = c - points[i, k]
            if np.linalg.norm(d - axes[i, k] * (d @ axes[i, k])) > 1e-6:
                return None
        centres.append(c)
    centres_arr = np.array(centres)
    arm = chain(g, q, upto=3)  # frame after Rz(q3) G_3
    arm_pre = arm @ np.linalg.inv(g[3])
    c_arm = np.einsum("nji,nj->ni", arm_pre[:, :3, :3], centres_arr - arm_pre[:, :3, 3])
    c_fl = np.einsum("nji,nj->ni", flange[:, :3, :3], centres_arr - flange[:, :3, 3])
    if not (np.allclose(c_arm, c_arm[0], atol=1e-6) and np.allclose(c_fl, c_fl[0], atol=1e-6)):
        return None
    centre_arm = np.append(c_arm[0], 1.0)
    # Stretched arm: q3 maximising the distance of c from axis 2 (q1 = q2 = 0).
    grid = np.deg2rad(np.arange(-180.0, 180.0, 0.25))
    qq = np.zeros((grid.size, N_JOINTS))
    qq[:, 2] = grid
    pre = chain(g, qq, upto=2) @ _rz(grid) @ centre_arm[None, :, None]
    rot0, origin0 = forward_frames(model.dh_internal(), qq[:1], model.convention)
    ax, pt = _axes(model, rot0, origin0)
    d = pre[:, :3, 0] - pt[0, 1]
    dist = np.linalg.norm(d - np.outer(d @ ax[0, 1], ax[0, 1]), axis=1)
    x1 = rot0[0, 1, :, 0]
    return WristGeometry(
        g, centre_arm, c_fl[0], float(grid[np.argmax(dist)]), math.atan2(x1[1], x1[0])
    )


def _wrap(q: FloatArray) -> FloatArray:
    out: FloatArray = (q + np.pi) % (2 * np.pi) - np.pi
    return out


def _rot_z(cos: FloatArray, sin: FloatArray, v: FloatArray) -> FloatArray:
    """``Rz(q) v`` for vectors (m, 3) given ``cos q, sin q`` (m,)."""
    out = np.empty_like(v)
    out[:, 0] = cos * v[:, 0] - sin * v[:, 1]
    out[:, 1] = sin * v[:, 0] + cos * v[:, 1]
    out[:, 2] = v[:, 2]
    return out


def _ez_cross(v: FloatArray) -> FloatArray:
    """``e_z × v`` for vectors (m, 3)."""
    out = np.zeros_like(v)
    out[:, 0] = -v[:, 1]
    out[:, 1] = v[:, 0]
    return out


def _arm_point_jacobian(geo: WristGeometry, q: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Wrist centre (m, 3) [mm] and its Jacobian (m, 3, 3) [mm/rad] for arm joints (m, 3)."""
    g = geo.g
    r0, r1, r2 = g[0][:3, :3], g[1][:3, :3], g[2][:3, :3]
    c, s = np.cos(q), np.sin(q)
    v3 = _rot_z(c[:, 2], s[:, 2], np.broadcast_to(geo.centre_arm[:3], q.shape))
    v2 = _rot_z(c[:, 1], s[:, 1], v3 @ r2.T + g[2][:3, 3])
    v1 = _rot_z(c[:, 0], s[:, 0], v2 @ r1.T + g[1][:3, 3])
    p = v1 @ r0.T + g[0][:3, 3]
    j1 = _ez_cross(v1) @ r0.T
    j2 = _rot_z(c[:, 0], s[:, 0], _ez_cross(v2) @ r1.T) @ r0.T
    j3 = _rot_z(c[:, 1], s[:, 1], _ez_cross(v3) @ r2.T) @ r1.T
    j3 = _rot_z(c[:, 0], s[:, 0], j3) @ r0.T
    return p, np.stack([j1, j2, j3], axis=2)


def _arm_solve(
    geo: WristGeometry, model: RobotModel, centre: FloatArray, seeds: FloatArray
) -> tuple[FloatArray, np.ndarray]:
    """Damped Newton for q1..q3 placing the wrist centre; seeds (m, 3) [rad], centre (m, 3).

    A row whose error has not halved in 4 iterations is given up (out of reach from its
    seed's side)."""
    del model
    q = seeds.copy()
    m = q.shape[0]
    done = np.zeros(m, dtype=bool)
    active = np.arange(m)
    best = np.full(m, np.inf)
    since = np.zeros(m, dtype=int)
    for _ in range(ARM_ITERATIONS):
        p, jac = _arm_point_jacobian(geo, q[active])
        err = centre[active] - p
        norm = np.linalg.norm(err, axis=1)
        better = norm < 0.5 * best[active]
        best[active[better]] = norm[better]
        since[active] = np.where(better, 0, since[active] + 1)
        ok = norm < ARM_TOL_MM
        done[active[ok]] = True
        keep = ~ok & (since[active] < 4)
        active, err, norm, jac = active[keep], err[keep], norm[keep], jac[keep]
        if active.size == 0:
            break
        lam2 = np.minimum(1.0, norm)[:, None, None] * np.eye(3)
        jt = np.swapaxes(jac, 1, 2)
        dq = np.linalg.solve(jt @ jac + lam2, (jt @ err[..., None]))[..., 0]
        big = np.max(np.abs(dq), axis=1)
        dq *= np.minimum(1.0, 0.5 / np.maximum(big, 1e-300))[:, None]
        q[active] += dq
    return _wrap(q), done


def _plane_angle(
    axis: FloatArray, point: FloatArray, frm: FloatArray, to: FloatArray
) -> FloatArray:
    """Rotation about ``axis`` (through ``point``) taking ``frm`` closest to ``to`` (n,) [rad]."""
    u, v = frm - point, to - point
    u = u - axis * np.einsum("ni,ni->n", u, axis)[:, None]
    v = v - axis * np.einsum("ni,ni->n", v, axis)[:, None]
    out: FloatArray = np.arctan2(
        np.einsum("ni,ni->n", axis, np.cross(u, v)), np.einsum("ni,ni->n", u, v)
    )
    return out


def _wrist(geo: WristGeometry, arm: FloatArray, target: FloatArray) -> FloatArray:
    """Both wrist solutions for arm joints (m, 3) [rad] and target flanges (m, 4, 4):
    (m, 2, 3) [rad] (NaN where the wrist cannot reach the orientation)."""
    g = geo.g
    m = arm.shape[0]
    # Rotation of G_0 Rz(q1) G_1 Rz(q2) G_2 Rz(q3) G_3 (3x3 only: translations not needed).
    pre = g[0][:3, :3] @ _rz3(arm[:, 0]) @ g[1][:3, :3] @ _rz3(arm[:, 1]) @ g[2][:3, :3]
    pre = pre @ _rz3(arm[:, 2]) @ g[3][:3, :3]
    mm = np.swapaxes(pre, 1, 2) @ target[:, :3, :3] @ g[6][:3, :3].T
    a, b = g[4][:3, :3], g[5][:3, :3]
    u = a[2, :]  # Aᵀ e_z
    v = b[:, 2]  # B e_z
    k1 = u[0] * v[0] + u[1] * v[1]
    k2 = u[1] * v[0] - u[0] * v[1]
    rhs = (mm[:, 2, 2] - u[2] * v[2]) / max(math.hypot(k1, k2), 1e-12)
    phi = math.atan2(k2, k1)
    base = np.arccos(np.clip(rhs, -1.0, 1.0))
    reachable = np.abs(rhs) <= 1.0 + 1e-9
    out = np.full((m, 2, 3), np.nan)
    for s, sign in enumerate((1.0, -1.0)):
        q5 = phi + sign * base
        rz5 = _rz3(q5)
        w = a @ rz5 @ v  # (m, 3): M e_z = Rz(q4) w
        mz = mm[:, :, 2]
        q4 = np.arctan2(mz[:, 1], mz[:, 0]) - np.arctan2(w[:, 1], w[:, 0])
        singular = np.hypot(w[:, 0], w[:, 1]) < 1e-9
        q4 = np.where(singular, 0.0, q4)
        rz4 = _rz3(q4)
        ab = a @ rz5 @ b
        rest = np.swapaxes(ab, 1, 2) @ np.swapaxes(rz4, 1, 2) @ mm
        q6v = np.arctan2(rest[:, 1, 0], rest[:, 0, 0])
        back = rz4 @ ab @ _rz3(q6v)
        good = reachable & (np.linalg.norm(back - mm, axis=(1, 2)) < 10 * CHECK_TOL_RAD)
        out[:, s] = np.where(good[:, None], np.stack([q4, q5, q6v], axis=1), np.nan)
    return _wrap(out)


@dataclass(frozen=True)
class Solutions:
    """Nominal IK solutions of n targets.

    Attributes
    ----------
    joints_deg : ndarray, shape (n, k, 6)
        Candidates [deg] (NaN rows where fewer than k exist); all within the joint limits.
    valid : ndarray of bool, shape (n, k)
    shoulder, elbow, wrist : ndarray of int, shape (n, k)
        Branch signs (:class:`calib.programs.sites.Configuration`).
    """

    joints_deg: FloatArray
    valid: np.ndarray
    shoulder: np.ndarray
    elbow: np.ndarray
    wrist: np.ndarray


def _arm_signs(geo: WristGeometry, convention: str, arm: FloatArray) -> tuple[np.ndarray, ...]:
    """``shoulder, elbow`` (each (m,) int) of arm joints (m, 3) [rad]."""
    g = geo.g
    m = arm.shape[0]
    pre1 = np.broadcast_to(g[0], (m, 4, 4)) @ _rz(arm[:, 0])
    pre2 = pre1 @ g[1]
    pre3 = pre2 @ _rz(arm[:, 1]) @ g[2]
    c = (pre3 @ _rz(arm[:, 2]) @ geo.centre_arm)[:, :3]
    x1 = (pre2 if convention == "dh" else pre1)[:, :3, 0]
    o1, o2, o3 = g[0][:3, 3], pre2[:, :3, 3], pre3[:, :3, 3]
    shoulder = np.where(np.einsum("ni,ni->n", c - o1, x1) > 0, 1, -1)
    h = c.copy()
    h[:, 2] = 0.0
    h /= np.maximum(np.linalg.norm(h, axis=1, keepdims=True), 1e-12)
    zxh = np.stack([-h[:, 1], h[:, 0], np.zeros(m)], axis=1)  # e_z × h
    val = np.einsum("ni,ni->n", zxh, np.cross(c - o2, o3 - o2))
    elbow = np.where(val < 0, 1, -1)
    return shoulder, elbow


def branch_signs(model: RobotModel, joints_deg: FloatArray) -> tuple[np.ndarray, ...]:
    """``shoulder, elbow, wrist`` signs (each (n,) int) of the controller's joints (n, 6)
    [deg] on ``model`` (definitions: :class:`calib.programs.sites.Configuration`; ``o_2``,
    ``o_3`` are the origins of the transforms just before ``Rz(q_2)`` and ``Rz(q_3)``; on a
    UR-shaped arm the shoulder and elbow are :func:`calib.filter.ur_ik.ur_signs`').

    Raises
    ------
    ValueError
        The model has no closed-form solver (neither a spherical wrist nor UR's shape).
    """
    q = np.asarray(joints_deg, dtype=float)
    table = to_table_deg(model, q)
    geo = wrist_geometry(model)
    if geo is not None:
        shoulder, elbow = _arm_signs(geo, model.convention, np.deg2rad(table[:, :3]))
    else:
        ur = ur_signs(model, table)
        if ur is None:
            raise ValueError(_no_solver(model))
        shoulder, elbow, _ = ur
    return shoulder, elbow, np.where(q[:, 4] >= 0, 1, -1)


def closed_form_is_complete(model: RobotModel) -> bool:
    """:func:`nominal_solutions` finds every solution (spherical wrist, exact UR shape)."""
    shape = ur_shape(model, snap=False)
    return wrist_geometry(model) is not None or (shape is not None and shape.exact)


def _no_solver(model: RobotModel) -> str:
    return (
        f"robot {model.name}: the filter solves a spherical wrist (axes 4, 5, 6 meeting in "
        "one point) or UR's offset wrist, and this model has neither"
    )


def nominal_solutions(
    model: RobotModel, flange: FloatArray, near_deg: FloatArray | None = None
) -> Solutions:
    """All nominal IK solutions within the joint limits of flange frames (n, 4, 4) [mm], in
    the controller's joint angles (:mod:`calib.filter.kin`).

    ``near_deg`` (n, 6) (NaN rows for none), the controller's: per joint, of the whole-turn
    variants within the limits, only the one nearest it is kept (UR's "nearest q"); without
    it every variant is a candidate.

    Raises
    ------
    ValueError
        The model has neither a spherical wrist nor UR's shape (no closed form).
    """
    n = flange.shape[0]
    limits = np.deg2rad(joint_limits_deg(model))
    geo = wrist_geometry(model)
    if geo is not None:
        base, base_ok, sh, el = _spherical(geo, model, flange)
    else:
        ref = None if near_deg is None else to_table_deg(model, np.asarray(near_deg, float))
        got = ur_solutions(model, flange, ref)
        if got is None:
            raise ValueError(_no_solver(model))
        base, base_ok = got
        sh = np.tile([s for s, _w, _e in ORDER], (n, 1))
        el = np.tile([e for _s, _w, e in ORDER], (n, 1))
    base = np.deg2rad(to_controller_deg(model, np.rad2deg(base)))
    base = np.where(whole_turns(model), _wrap(base), base)
    base = np.where(base_ok[..., None], base, 0.0)
    cand, valid, per_base = turn_variants(base, base_ok, limits, near_deg)
    k = cand.shape[1]
    joints = np.rad2deg(np.where(valid[..., None], cand, np.nan))
    shoulder = np.repeat(sh, per_base, axis=1)
    elbow = np.repeat(el, per_base, axis=1)
    wr = np.where(np.nan_to_num(joints[..., 4]) >= 0, 1, -1)
    assert shoulder.shape == (n, k)
    return Solutions(joints, valid, shoulder, elbow, wr)


def _spherical(
    geo: WristGeometry, model: RobotModel, flange: FloatArray
) -> tuple[FloatArray, np.ndarray, np.ndarray, np.ndarray]:
    """The 8 base solutions of a spherical wrist (module docstring): table angles (n, 8, 6)
    [rad], validity (n, 8), shoulder and elbow signs (n, 8)."""
    n = flange.shape[0]
    centre = flange[:, :3, 3] + np.einsum("nij,j->ni", flange[:, :3, :3], geo.centre_flange)
    # Four arm seeds per target.
    az = np.arctan2(centre[:, 1], centre[:, 0]) - geo.forward_azimuth_rad
    seeds = np.zeros((n, 4, 3))
    for s, (dq1, dq3) in enumerate(((0.0, 0.5), (0.0, -0.5), (1.0, 0.5), (1.0, -0.5))):
        seeds[:, s, 0] = az + dq1 * np.pi
        seeds[:, s, 2] = geo.q3_stretched_rad + dq3 * np.pi
    flat = seeds.reshape(-1, 3)
    cflat = np.repeat(centre, 4, axis=0)
    # q2 aimed: rotate about axis 2 so the seed's centre comes closest to the target's.
    g = geo.g
    f1 = np.broadcast_to(g[0], (flat.shape[0], 4, 4)) @ _rz(flat[:, 0]) @ g[1]
    p = (f1 @ _rz(flat[:, 1]) @ g[2] @ _rz(flat[:, 2]) @ geo.centre_arm)[:, :3]
    flat[:, 1] += _plane_angle(f1[:, :3, 2], f1[:, :3, 3], p, cflat)
    arm, ok = _arm_solve(geo, model, cflat, flat)
    arm = arm.reshape(n, 4, 3)
    ok = ok.reshape(n, 4)
    # Merge duplicates (same arm solution from two seeds).
    for s in range(1, 4):
        for r in range(s):
            same = np.max(np.abs(_wrap(arm[:, s] - arm[:, r])), axis=1) < 1e-6
            ok[:, s] &= ~(same & ok[:, r])
    sh, el = (v.reshape(n, 4) for v in _arm_signs(geo, model.convention, arm.reshape(-1, 3)))
    wrist = _wrist(geo, arm.reshape(-1, 3), np.repeat(flange, 4, axis=0)).reshape(n, 4, 2, 3)
    base = np.concatenate([np.repeat(arm[:, :, None, :], 2, axis=2), wrist], axis=3)
    base = base.reshape(n, 8, N_JOINTS)
    base_ok = np.repeat(ok, 2, axis=1) & np.all(np.isfinite(base), axis=2)
    # Merge wrist duplicates (q5 = 0: both wrist solutions are one).
    for s in range(1, 8, 2):
        same = np.max(np.abs(_wrap(base[:, s] - base[:, s - 1])), axis=1) < 1e-9
        base_ok[:, s] &= ~(same & base_ok[:, s - 1])
    return base, base_ok, np.repeat(sh, 2, axis=1), np.repeat(el, 2, axis=1)


__all__ = [
    "Solutions",
    "branch_signs",
    "closed_form_is_complete",
    "fixed_transforms",
    "flange_frames",
    "nominal_solutions",
    "wrist_geometry",
]
