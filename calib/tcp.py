"""Predicted TCP position accuracy from a parameter covariance, up to a rigid motion.

**What is propagated.** A covariance ``C`` (shape ``(k, k)``, internal units) of the free
parameters (DH errors, tool point, anchors) maps to the tool point at poses ``q_1..q_m`` through
the position Jacobian ``A = ∂p/∂x`` (shape ``(3m, k)``; anchor parameters do not move the
tool, their columns are zero): ``Σ_p = A C Aᵀ``.

**What is removed.** Cable lengths are distances from the anchor. Moving the robot *and* the
anchor by the same rigid motion changes no reading, so distance-only data cannot locate the
calibrated robot in any external frame: :mod:`calib.identifiability` leaves ``theta1`` (rotation
about base z) and ``d1`` (shift along base z) out for that reason, the anchor ``P0`` absorbing
them, and a tilt or horizontal shift of the base is no parameter of the model at all. What the
calibration delivers is the *shape* of the workspace; a user registers it to the cell
(best rigid alignment, as the simulator's truth comparison does). So the predicted error is
that of the positions after best rigid alignment: to first order, the component of
``δp = A δx`` (all poses stacked) outside the six rigid-motion directions
``δp_i = t + ω × p_i``. With ``G`` (shape ``(3m, 6)``) spanning them and
``P = I − G (GᵀG)⁻¹ Gᵀ``, the aligned covariance is ``P A C Aᵀ P``, computed as
``B = P A`` and the per-pose variances ``diag(B C Bᵀ)`` (no ``3m × 3m`` matrix).

**Figures.** Per pose ``σ_i = sqrt(trace Σ_i)`` [mm], the expected 3-D position error.
``rms_mm = sqrt(mean σ_i²)`` (the expected RMS aligned error over the sample) and
``max_mm = max σ_i``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.cable import N_KIN, ParamLayout, kinematic_parts
from calib.kinematics import N_JOINTS, FloatArray, forward_position, position_jacobian
from calib.models import RobotModel
from calib.problem import BoolArray, Problem

#: Default size of the workspace sample.
WORKSPACE_POSES = 500


@dataclass(frozen=True)
class TcpUncertainty:
    """Predicted 1σ TCP position error after best rigid alignment [mm].

    Attributes
    ----------
    rms_mm, max_mm : float
        RMS and maximum of the per-pose σ over the workspace sample.
    sigma_mm : ndarray, shape (m,)
        Per-pose σ.
    """

    rms_mm: float
    max_mm: float
    sigma_mm: FloatArray

    def to_dict(self) -> dict[str, float]:
        """``{"rms": …, "max": …}`` in mm, the form of ``tcp_uncertainty_mm`` in result.json."""
        return {"rms": self.rms_mm, "max": self.max_mm}


def joint_limits_deg(model: RobotModel) -> FloatArray:
    """The model's joint limits, shape (6, 2) [deg]: :meth:`RobotModel.limits_deg`, their one
    home, which every caller reads. Kept only for ``calib/filter/`` (``correct.py``,
    ``branches.py``, ``nearest.py``), which is being moved: remove it when they read the model."""
    return model.limits_deg()


def workspace_sample_deg(
    model: RobotModel, n: int = WORKSPACE_POSES, seed: int = 0, min_z_mm: float | None = None
) -> FloatArray:
    """``n`` poses uniform within the joint limits, shape (n, 6) [deg], seeded.

    With ``min_z_mm``, only poses whose tool point (nominal model) is above it are kept.
    """
    rng = np.random.default_rng(seed)
    limits = model.limits_deg()
    out = np.empty((0, N_JOINTS))
    for _ in range(100):
        q = rng.uniform(limits[:, 0], limits[:, 1], size=(2 * n, N_JOINTS))
        if min_z_mm is not None:
            pos = forward_position(
                model.dh_internal(), model.table_rad(q), model.tool_mm, model.convention
            )
            q = q[pos[:, 2] >= min_z_mm]
        out = np.vstack([out, q])
        if out.shape[0] >= n:
            return out[:n]
    raise ValueError(f"min_z_mm: fewer than {n} workspace poses have the tool above {min_z_mm}")


def rigid_directions(points_mm: FloatArray) -> FloatArray:
    """Basis of the small rigid motions of a point set, shape (3m, 6).

    Columns 0..2 translate every point; columns 3..5 rotate about the points' centroid
    (``δp_i = ω × (p_i − p̄)``). ``points_mm`` has shape (m, 3), rows ordered as the stacked
    ``(x_1, y_1, z_1, x_2, …)`` vector.
    """
    c = points_mm - points_mm.mean(axis=0)
    m = points_mm.shape[0]
    g = np.zeros((m, 3, 6))
    g[:, :, :3] = np.eye(3)
    # ω × c = [c]ₓᵀ ω: column e_a gives e_a × c.
    for a in range(3):
        e = np.zeros(3)
        e[a] = 1.0
        g[:, :, 3 + a] = np.cross(e, c)
    return g.reshape(3 * m, 6)


def remove_rigid(points_mm: FloatArray, a: FloatArray) -> FloatArray:
    """Project the columns of ``a`` (shape (3m, k)) off the rigid motions of ``points_mm``."""
    g = rigid_directions(points_mm)
    q, _ = np.linalg.qr(g)
    out: FloatArray = a - q @ (q.T @ a)
    return out


def aligned_tcp_jacobian(
    model: RobotModel, layout: ParamLayout, theta: FloatArray, free: BoolArray, q_deg: FloatArray
) -> FloatArray:
    """Tool-point Jacobian of the free parameters with the rigid motions removed, (3m, k).

    Rows ``(x_1, y_1, z_1, x_2, …)`` of the ``m`` poses ``q_deg`` (m, 6) [deg]; columns the
    free parameters (internal units; anchor columns are zero). ``σ² = rowᵀ C row`` summed over
    a pose's three rows is its aligned TCP variance for a parameter covariance ``C``.
    """
    dh, tool = kinematic_parts(model, theta)
    pos, jac = position_jacobian(dh, model.table_rad(q_deg), tool, model.convention)  # (m,3,27)
    m = np.asarray(q_deg).shape[0]
    a_full = np.zeros((3 * m, layout.size))
    a_full[:, :N_KIN] = jac.reshape(3 * m, N_KIN)
    return remove_rigid(pos, a_full[:, np.asarray(free, dtype=bool)])


def tcp_uncertainty(
    model: RobotModel,
    layout: ParamLayout,
    theta: FloatArray,
    free: BoolArray,
    cov_free: FloatArray,
    *,
    q_deg: FloatArray | None = None,
    n_poses: int = WORKSPACE_POSES,
    seed: int = 0,
) -> TcpUncertainty:
    """Predicted aligned TCP σ over a workspace sample (see the module docstring).

    Parameters
    ----------
    theta : ndarray, shape (p,)
        Full parameter vector where the Jacobian is taken (the fit or the nominal model).
    free : ndarray of bool, shape (p,)
    cov_free : ndarray, shape (k, k)
        Covariance of the free parameters, internal units (mm², rad², mm·rad).
    q_deg : ndarray, shape (m, 6), optional
        Workspace poses [deg]; default :func:`workspace_sample_deg` ``(n_poses, seed)``.
    """
    free = np.asarray(free, dtype=bool)
    k = int(np.count_nonzero(free))
    if free.shape != (layout.size,):
        raise ValueError(f"free: expected shape ({layout.size},), got {free.shape}")
    if cov_free.shape != (k, k):
        raise ValueError(
            f"cov_free: expected shape ({k}, {k}) for {k} free parameters, got {cov_free.shape}"
        )
    q = workspace_sample_deg(model, n_poses, seed) if q_deg is None else np.asarray(q_deg)
    b = aligned_tcp_jacobian(model, layout, theta, free, q)
    m = q.shape[0]
    var = np.einsum("ij,jk,ik->i", b, cov_free, b).reshape(m, 3).sum(axis=1)
    sigma = np.sqrt(np.clip(var, 0.0, None))
    return TcpUncertainty(float(np.sqrt(np.mean(sigma**2))), float(sigma.max()), sigma)


def tcp_uncertainty_for_problem(
    problem: Problem,
    x: FloatArray,
    cov_free: FloatArray,
    *,
    q_deg: FloatArray | None = None,
    n_poses: int = WORKSPACE_POSES,
    seed: int = 0,
) -> TcpUncertainty:
    """:func:`tcp_uncertainty` for a :class:`~calib.problem.Problem` at free values ``x``
    (shape (k,)), e.g. the fit and the free-parameter covariance ``identify`` computes."""
    return tcp_uncertainty(
        problem.model,
        problem.layout,
        problem.full(x),
        problem.free,
        cov_free,
        q_deg=q_deg,
        n_poses=n_poses,
        seed=seed,
    )


def aligned_position_error_mm(points_mm: FloatArray, reference_mm: FloatArray) -> FloatArray:
    """Distance of each point to its reference after the best rigid alignment, shape (m,) [mm].

    The rigid motion (rotation and translation, no scale) minimising the sum of squared
    distances is applied to ``points_mm`` (shape (m, 3)); ``reference_mm`` has the same shape.

    Raises
    ------
    ValueError
        Shapes differ, are not (m, 3), or m < 3.
    """
    pa, pb = np.asarray(points_mm, dtype=float), np.asarray(reference_mm, dtype=float)
    if pa.ndim != 2 or pa.shape[1] != 3 or pa.shape != pb.shape or pa.shape[0] < 3:
        raise ValueError(
            f"points_mm, reference_mm: need equal shapes (m>=3, 3), got {pa.shape} and {pb.shape}"
        )
    # Imported here: identify (which needs the rest of this module) never aligns points.
    from scipy.spatial.transform import Rotation

    ca, cb = pa.mean(axis=0), pb.mean(axis=0)
    rot, _ = Rotation.align_vectors(pb - cb, pa - ca)
    moved = rot.apply(pa - ca) + cb
    out: FloatArray = np.linalg.norm(moved - pb, axis=1)
    return out


__all__ = [
    "TcpUncertainty",
    "aligned_position_error_mm",
    "joint_limits_deg",
    "remove_rigid",
    "tcp_uncertainty",
    "tcp_uncertainty_for_problem",
    "workspace_sample_deg",
]
