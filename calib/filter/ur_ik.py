"""Closed-form inverse kinematics of Universal Robots' offset wrist: all 8 solutions.

No UR wrist is spherical: axes 2, 3, 4 are parallel and axis 5 is offset from axis 4 by
``d5``, axis 6 from axis 5 by ``d6``. The classic analytic solution (K. P. Hawkins,
"Analytic Inverse Kinematics for the Universal Robots UR-5/UR-10 Arms", 2013, as in
ros-industrial's ``ur_kinematics/src/ur_kin.cpp``) is rewritten here for any classic-DH table
of that shape, whatever the signs of its twists (:func:`ur_shape`), with ``φ_i = q_i + θ_i``
the DH angles, ``o_i, z_i`` the origin and z axis of DH frame ``i`` (axis ``i+1`` is ``z_i``):

1. **Shoulder (φ1).** Remove the last transform's fixed part: ``F = T·(Tz(d6)Tx(a6)Rx(α6))⁻¹``
   has its origin at ``o5`` and its z axis along axis 6. Axes 2, 3, 4 share the direction
   ``n = z1 = Rz(φ1)·Rx(α1)e_z``, and every point of the arm between ``o1`` and ``o5`` lies
   in the plane ``n·(p − o1) = D``, ``D = d2 + d3 + d4`` (axis 5 is normal to ``n``). With
   ``w = o5 − o1`` and ``v = Rx(α1)e_z``: ``A cos φ1 + B sin φ1 = D − v_z w_z`` (``A = v_x w_x
   + v_y w_y``, ``B = v_x w_y − v_y w_x``), two solutions (shoulder left/right).
2. **Wrist (φ5).** ``n·z5 = −sin α4 sin α5 cos φ5`` and ``|sin φ5| = |n × z5|`` (``α4, α5 =
   ±90°``): two solutions (the wrist flip, the sign of ``sin φ5``).
3. **φ6** from ``n`` seen in ``F``: ``Rz(φ6)·(R_Fᵀ n) = Rx(α5)ᵀRz(φ5)ᵀ(0, sin α4, cos α4)``.
   At the wrist singularity (``sin φ5 = 0``: axis 6 parallel to axes 2–4) ``φ6`` is free and
   set to the reference's (or 0).
4. **Planar arm (φ2, φ3, φ4).** ``R4 = R_F Rz(φ6)ᵀ Rx(α5)ᵀ Rz(φ5)ᵀ``, ``o4 = o5 − d5 z4``,
   ``R1ᵀ(o4 − o1) = (a2 cos φ2 + a3 cos φ23, a2 sin φ2 + a3 sin φ23, D)``: ``cos φ3`` by the
   law of cosines (elbow: the sign of ``sin φ3``), ``φ2`` from the triangle, and
   ``φ4 = φ234 − φ2 − φ3`` with ``Rz(φ234) = R1ᵀ R4 Rx(α4)ᵀ``.

Every candidate is checked by forward kinematics (:data:`CHECK_TOL_MM`) and dropped (NaN)
otherwise. A model of nearly that shape (a UR's own factory calibration: small ``a1, a4, a5``,
twists off by millidegrees, and ``d`` of hundreds of metres on the nearly parallel axes 2-4)
is solved on its UR-shaped neighbour (:func:`ur_shape`: the UR-shaped table nearest it in
forward kinematics) and each solution refined by Newton on the model itself
(:func:`calib.ik.solve_ik`), so the eight branches are the neighbour's. All angles here are
the DH table's (the filter's boundary, :mod:`calib.filter.kin`, converts the controller's);
arrays are batched over targets.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

from calib.filter.kin import table_model
from calib.ik import IKOptions, solve_ik
from calib.kinematics import N_JOINTS, FloatArray, forward_frames
from calib.models import RobotModel

#: A candidate whose flange is further than this from the target is dropped [mm].
CHECK_TOL_MM = 1e-7
#: A table within these of UR's shape is solved on its UR-shaped neighbour, then refined.
SNAP_ALPHA_DEG = 1.0
SNAP_LENGTH_MM = 5.0
#: Poses of the neighbour's fit, and how close it must come to the table [mm].
FIT_POSES = 64
FIT_TOL_MM = 20.0
LIBRARY = Path(__file__).resolve().parent.parent / "robots" / "library"
#: How far past its reach the neighbour still gives a seed (the cosine's excess).
SEED_SLACK = 0.05
#: Newton refinement of a near-UR model from the neighbour's solutions.
REFINE = IKOptions(max_iterations=30, tol_mm=1e-8, tol_deg=1e-8, stall_iterations=6)
#: Branch order of the 8 solutions: (shoulder, wrist, elbow) signs, shoulder slowest.
ORDER = [(s, w, e) for s in (1, -1) for w in (1, -1) for e in (1, -1)]


@dataclass(frozen=True)
class URShape:
    """A classic-DH table of UR's shape (internal units: mm, rad), ``exact`` when the model
    itself has it, else its UR-shaped neighbour's."""

    dh: FloatArray  # (6, 4): alpha_rad, a_mm, d_mm, theta_rad
    exact: bool


def ur_shape(model: RobotModel, snap: bool = True) -> URShape | None:
    """The UR shape of ``model``: classic DH, ``α2 = α3 = 0``, ``|α1| = |α4| = |α5| = 90°``,
    ``a1 = a4 = a5 = 0``. With ``snap``, a table within :data:`SNAP_ALPHA_DEG` and
    :data:`SNAP_LENGTH_MM` of that gives its UR-shaped neighbour (:func:`_neighbour`). None
    otherwise."""
    if model.convention != "dh":
        return None
    dh = model.dh_internal()
    want = _snapped(dh)
    d_alpha = float(np.max(np.abs(want[:, 0] - dh[:, 0])))
    d_len = float(np.max(np.abs(want[:, 1] - dh[:, 1])))
    if d_alpha < 1e-12 and d_len < 1e-9:
        return URShape(want, True)
    if snap and d_alpha <= math.radians(SNAP_ALPHA_DEG) and d_len <= SNAP_LENGTH_MM:
        near = _neighbour(np.ascontiguousarray(dh).tobytes())
        return None if near is None else URShape(near, False)
    return None


def _snapped(dh: FloatArray) -> FloatArray:
    """``dh`` with ``α1, α4, α5`` set to ±90°, ``α2 = α3 = 0`` and ``a1 = a4 = a5 = 0``."""
    want = dh.copy()
    for j in (0, 3, 4):
        want[j, 0] = math.copysign(math.pi / 2, dh[j, 0])
        want[j, 1] = 0.0
    want[1:3, 0] = 0.0
    return want


def _published_starts() -> list[FloatArray]:
    """UR's published ``(d1, a2, a3, d4, d5, d6)`` [mm] of the library's UR arms (their one
    home: calib/robots/library/ur*.toml), fit starts for a factory-calibrated table."""
    out = []
    for path in sorted(LIBRARY.glob("ur*.toml")):
        joints = tomllib.loads(path.read_text("utf-8"))["joints"]
        out.append(
            np.array(
                [joints[0]["d_mm"], joints[1]["a_mm"], joints[2]["a_mm"]]
                + [joints[k]["d_mm"] for k in (3, 4, 5)]
            )
        )
    return out


def _table(x: FloatArray, shape_of: FloatArray) -> FloatArray:
    """The UR-shaped table of fit parameters ``x`` = (d1, a2, a3, D, d5, d6, θ1..θ6)."""
    out = _snapped(shape_of)
    out[:, 1] = (0.0, x[1], x[2], 0.0, 0.0, shape_of[5, 1])
    out[:, 2] = (x[0], 0.0, 0.0, x[3], x[4], x[5])
    out[:, 3] = x[6:12]
    return out


@lru_cache(maxsize=16)
def _neighbour(raw: bytes) -> FloatArray | None:
    """The UR-shaped table nearest a near-UR table ``raw`` ((6, 4) internal units) in forward
    kinematics: least squares over :data:`FIT_POSES` poses from the best of the snapped
    table and UR's published tables (a factory calibration's table can carry ``d`` of
    hundreds of metres on the nearly parallel axes 2-4, which snapping alone would keep).
    None when the fit stays further than :data:`FIT_TOL_MM` from the table anywhere."""
    dh = np.frombuffer(raw, dtype=float).reshape(N_JOINTS, 4)
    q = np.random.default_rng(0).uniform(-np.pi, np.pi, size=(FIT_POSES, N_JOINTS))
    rot, org = forward_frames(dh, q, "dh")
    want_p, want_r = org[:, N_JOINTS], rot[:, N_JOINTS]

    def residual(x: FloatArray) -> FloatArray:
        r, o = forward_frames(_table(x, dh), q, "dh")
        out: FloatArray = np.concatenate(
            [(o[:, N_JOINTS] - want_p).ravel(), 100.0 * (r[:, N_JOINTS] - want_r).ravel()]
        )
        return out

    starts = [
        np.concatenate(
            [[dh[0, 2], dh[1, 1], dh[2, 1], dh[1:4, 2].sum(), dh[4, 2], dh[5, 2]], dh[:, 3]]
        )
    ]
    starts += [np.concatenate([p, np.zeros(N_JOINTS)]) for p in _published_starts()]
    best = min(starts, key=lambda x: float(np.sum(residual(x) ** 2)))
    fit = least_squares(residual, best, method="lm", xtol=1e-12, ftol=1e-12)
    table = _table(fit.x, dh)
    _, o = forward_frames(table, q, "dh")
    if float(np.max(np.linalg.norm(o[:, N_JOINTS] - want_p, axis=1))) > FIT_TOL_MM:
        return None
    return table


def _wrap(q: FloatArray) -> FloatArray:
    out: FloatArray = (q + np.pi) % (2 * np.pi) - np.pi
    return out


def rz3(phi: FloatArray) -> FloatArray:
    """Rotations about z, (…, 3, 3), for angles (…) [rad]."""
    c, s = np.cos(phi), np.sin(phi)
    out = np.zeros((*np.shape(phi), 3, 3))
    out[..., 0, 0], out[..., 0, 1], out[..., 1, 0], out[..., 1, 1] = c, -s, s, c
    out[..., 2, 2] = 1.0
    return out


def _rx(alpha: float) -> FloatArray:
    c, s = math.cos(alpha), math.sin(alpha)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _acos2(x: FloatArray, slack: float) -> tuple[FloatArray, np.ndarray]:
    """``acos`` of ``x`` clipped to [-1, 1], and where ``|x| ≤ 1 + slack``."""
    ok = np.abs(x) <= 1.0 + slack
    return np.arccos(np.clip(x, -1.0, 1.0)), ok


def solve_dh(
    dh: FloatArray, flange: FloatArray, ref_rad: FloatArray | None = None, slack: float = 1e-9
) -> FloatArray:
    """The 8 DH-angle solutions (n, 8, 6) [rad] (``q + θ`` wrapped to (-π, π]; NaN rows where
    a branch does not exist) of flange frames (n, 4, 4) [mm] for a table of UR's shape
    ``dh`` (6, 4). Branch ``k`` has the signs ``ORDER[k]``. ``ref_rad`` (n, 6) DH angles
    (NaN for none) fixes ``φ6`` at the wrist singularity; ``slack`` lets a pose just out of
    the table's reach (``|cos| ≤ 1 + slack``) give its boundary solution (a seed)."""
    n = flange.shape[0]
    alpha, a, d = dh[:, 0], dh[:, 1], dh[:, 2]
    tail = np.eye(4)  # Tz(d6) Tx(a6) Rx(α6)
    tail[:3, :3] = _rx(alpha[5])
    tail[:3, 3] = (a[5], 0.0, d[5])
    f = flange @ np.linalg.inv(tail)
    r_f, o5 = f[:, :3, :3], f[:, :3, 3]
    w = o5 - np.array([0.0, 0.0, d[0]])
    v = _rx(alpha[0])[:, 2]
    big_d = d[1] + d[2] + d[3]
    lhs_a = v[0] * w[:, 0] + v[1] * w[:, 1]
    lhs_b = v[0] * w[:, 1] - v[1] * w[:, 0]
    rho = np.hypot(lhs_a, lhs_b)
    base1 = np.arctan2(lhs_b, lhs_a)
    acos1, ok1 = _acos2((big_d - v[2] * w[:, 2]) / np.maximum(rho, 1e-300), slack)
    ca4, sa4, ca5, sa5 = (
        math.cos(alpha[3]),
        math.sin(alpha[3]),
        math.cos(alpha[4]),
        math.sin(alpha[4]),
    )
    out = np.full((n, 8, N_JOINTS), np.nan)
    a2, a3 = a[1], a[2]
    for k, (s_sh, s_wr, s_el) in enumerate(ORDER):
        phi1 = base1 + s_sh * acos1
        r1 = rz3(phi1) @ _rx(alpha[0])
        nvec = r1[:, :, 2]
        nz5 = np.einsum("ni,ni->n", nvec, r_f[:, :, 2])
        # cos φ5 from n·z5; |sin φ5| = |n × z5| (axis 5 ⟂ n): atan2 keeps φ5 exact near 0, π.
        sin5 = np.linalg.norm(np.cross(nvec, r_f[:, :, 2]), axis=1)
        phi5 = s_wr * np.arctan2(sin5, (ca4 * ca5 - nz5) / (sa4 * sa5))
        ok5 = np.ones(n, dtype=bool)
        # φ6: Rz(φ6) (R_Fᵀ n) = Rx(α5)ᵀ Rz(φ5)ᵀ (0, sin α4, cos α4).
        n_f = np.einsum("nji,nj->ni", r_f, nvec)
        m = np.einsum("ij,nkj,k->ni", _rx(alpha[4]).T, rz3(phi5), np.array([0.0, sa4, ca4]))
        phi6 = np.arctan2(m[:, 1], m[:, 0]) - np.arctan2(n_f[:, 1], n_f[:, 0])
        singular = np.abs(np.sin(phi5)) < 1e-10
        if ref_rad is not None:
            phi6 = np.where(singular & np.isfinite(ref_rad[:, 5]), ref_rad[:, 5], phi6)
        phi6 = np.where(singular & ~np.isfinite(phi6), 0.0, phi6)
        r4 = r_f @ np.swapaxes(rz3(phi6), 1, 2) @ _rx(alpha[4]).T @ np.swapaxes(rz3(phi5), 1, 2)
        o4 = o5 - d[4] * r4[:, :, 2]
        p = np.einsum("nji,nj->ni", r1, o4 - np.array([0.0, 0.0, d[0]]))
        c3 = (p[:, 0] ** 2 + p[:, 1] ** 2 - a2 * a2 - a3 * a3) / (2.0 * a2 * a3)
        acos3, ok3 = _acos2(c3, slack)
        phi3 = s_el * acos3
        phi2 = np.arctan2(p[:, 1], p[:, 0]) - np.arctan2(a3 * np.sin(phi3), a2 + a3 * np.cos(phi3))
        m234 = np.swapaxes(r1, 1, 2) @ r4 @ _rx(alpha[3]).T
        phi4 = np.arctan2(m234[:, 1, 0], m234[:, 0, 0]) - phi2 - phi3
        sol = _wrap(np.stack([phi1, phi2, phi3, phi4, phi5, phi6], axis=1))
        good = ok1 & ok5 & ok3 & np.all(np.isfinite(sol), axis=1)
        out[:, k] = np.where(good[:, None], sol, np.nan)
    return out


def _check(dh: FloatArray, phi: FloatArray, flange: FloatArray) -> np.ndarray:
    """Per candidate (n, 8): its flange within :data:`CHECK_TOL_MM` of the target."""
    n = phi.shape[0]
    q = np.nan_to_num(phi).reshape(-1, N_JOINTS)
    table = dh.copy()
    table[:, 3] = 0.0
    rot, org = forward_frames(table, q, "dh")
    fl = np.repeat(flange, 8, axis=0)
    err = np.linalg.norm(org[:, N_JOINTS] - fl[:, :3, 3], axis=1)
    err += 1000.0 * np.linalg.norm(rot[:, N_JOINTS] - fl[:, :3, :3], axis=(1, 2))
    out: np.ndarray = (err < CHECK_TOL_MM).reshape(n, 8) & np.all(np.isfinite(phi), axis=2)
    return out


def ur_solutions(
    model: RobotModel, flange: FloatArray, ref_table_deg: FloatArray | None = None
) -> tuple[FloatArray, np.ndarray] | None:
    """The 8 nominal solutions of flange frames (n, 4, 4) [mm] on a UR-shaped ``model``:
    table angles (n, 8, 6) [rad] (the model's ``q``, wrapped) and their validity (n, 8);
    None when the model is not of UR's shape (:func:`ur_shape`). ``ref_table_deg`` (n, 6)
    fixes joint 6 at the wrist singularity."""
    shape = ur_shape(model)
    if shape is None:
        return None
    theta = shape.dh[:, 3]
    ref = None if ref_table_deg is None else np.deg2rad(ref_table_deg) + theta
    phi = solve_dh(shape.dh, flange, ref, 1e-9 if shape.exact else SEED_SLACK)
    if shape.exact:
        ok = _check(shape.dh, phi, flange)
        return _wrap(phi - theta), ok
    n = flange.shape[0]
    ok = np.all(np.isfinite(phi), axis=2)
    seeds = np.rad2deg(_wrap(np.nan_to_num(phi) - theta)).reshape(-1, N_JOINTS)
    fl = np.repeat(flange, 8, axis=0)
    sol = solve_ik(table_model(model), seeds, fl[:, :3, 3], fl[:, :3, :3], np.zeros(3), REFINE)
    q = _wrap(np.deg2rad(sol.joints_deg)).reshape(n, 8, N_JOINTS)
    ok = ok & sol.converged.reshape(n, 8)
    # Two seeds at a reach boundary (both elbows, both shoulders) may reach one solution.
    for k in range(1, 8):
        for r in range(k):
            same = np.max(np.abs(_wrap(q[:, k] - q[:, r])), axis=1) < 1e-7
            ok[:, k] &= ~(same & ok[:, r])
    return q, ok


def ur_signs(model: RobotModel, table_deg: FloatArray) -> tuple[np.ndarray, ...] | None:
    """``shoulder, elbow, wrist`` (each (n,) of ±1) of table angles (n, 6) [deg] on a
    UR-shaped model: the signs of :func:`solve_dh`'s branches (the ``±acos`` of φ1, of
    φ3 and of φ5), computed on the UR-shaped neighbour; None when not UR-shaped."""
    shape = ur_shape(model)
    if shape is None:
        return None
    dh = shape.dh
    phi = np.deg2rad(np.asarray(table_deg, dtype=float)) + dh[:, 3]
    table = dh.copy()
    table[:, 3] = 0.0
    _, org = forward_frames(table, phi, "dh")
    w = org[:, 5] - np.array([0.0, 0.0, dh[0, 2]])
    v = _rx(dh[0, 0])[:, 2]
    base1 = np.arctan2(v[0] * w[:, 1] - v[1] * w[:, 0], v[0] * w[:, 0] + v[1] * w[:, 1])
    shoulder = np.where(_wrap(phi[:, 0] - base1) >= 0, 1, -1)
    elbow = np.where(_wrap(phi[:, 2]) >= 0, 1, -1)
    wrist = np.where(_wrap(phi[:, 4]) >= 0, 1, -1)
    return shoulder, elbow, wrist


__all__ = ["ORDER", "URShape", "solve_dh", "ur_shape", "ur_signs", "ur_solutions"]
