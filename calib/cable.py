"""Cable model ``L = |p_tool(q) − P0| + c`` and its parameter layout.

The full parameter vector ``theta`` (shape ``(p,)``, internal units mm and rad) is:

====================  ===========================================================
index                 content
====================  ===========================================================
``0 .. 23``           DH errors, joint-major ``(dα_j [rad], da_j [mm], dd_j [mm], dθ_j [rad])``
``24 .. 26``          tool point error ``(dx, dy, dz)`` in the flange frame [mm]
``27 + 4k .. +2``     anchor ``k``: position P0 in the base frame [mm] (absolute, not an error)
``27 + 4k + 3``       anchor ``k``: indicator zero offset ``c`` [mm] (absolute)
====================  ===========================================================

A campaign may move the sensor: every sample carries an anchor index, and each anchor has its
own ``P0`` and ``c``. Parameter names are ``alpha1 a1 d1 theta1 … theta6 tool_x tool_y tool_z
p0_x p0_y p0_z offset``; for anchors after the first the anchor id is appended as ``p0_x@B``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.kinematics import (
    DH_FIELDS,
    N_JOINTS,
    FloatArray,
    IndexArray,
    JointTrig,
    forward_chain,
    forward_position,
    projected_jacobian,
)
from calib.models import RobotModel

N_DH = 4 * N_JOINTS
N_KIN = N_DH + 3  # DH errors + tool point
ANCHOR_FIELDS = ("p0_x", "p0_y", "p0_z", "offset")
#: Fewest samples that locate one anchor: :func:`multilaterate` solves a linear system in five
#: unknowns (P0, the offset c, and ``|P0|² − c²``), so it needs at least five rows.
MIN_ANCHOR_SAMPLES = 5
RAD_PER_DEG = np.pi / 180.0


@dataclass(frozen=True)
class ParamLayout:
    """Names, units and slices of the full parameter vector for a set of anchor ids."""

    anchors: tuple[str, ...]

    def __post_init__(self) -> None:
        if not self.anchors:
            raise ValueError("anchors: at least one anchor id is required")
        if len(set(self.anchors)) != len(self.anchors):
            raise ValueError(f"anchors: ids must be unique, got {self.anchors}")

    @property
    def size(self) -> int:
        return N_KIN + 4 * len(self.anchors)

    @property
    def names(self) -> tuple[str, ...]:
        out = [f"{f}{j + 1}" for j in range(N_JOINTS) for f in DH_FIELDS]
        out += ["tool_x", "tool_y", "tool_z"]
        for k, anchor in enumerate(self.anchors):
            suffix = "" if k == 0 else f"@{anchor}"
            out += [f"{f}{suffix}" for f in ANCHOR_FIELDS]
        return tuple(out)

    @property
    def is_angle(self) -> FloatArray:
        """Boolean mask, shape (p,): True where the internal unit is rad (display: deg)."""
        mask = np.zeros(self.size, dtype=bool)
        mask[0:N_DH:4] = True
        mask[3:N_DH:4] = True
        return mask

    @property
    def display_scale(self) -> FloatArray:
        """Factor, shape (p,), from internal units to display units (rad → deg, mm → mm)."""
        return np.where(self.is_angle, 180.0 / np.pi, 1.0)

    @property
    def units(self) -> tuple[str, ...]:
        return tuple("deg" if a else "mm" for a in self.is_angle)

    def anchor_slice(self, k: int) -> slice:
        return slice(N_KIN + 4 * k, N_KIN + 4 * k + 4)

    def index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise ValueError(f"unknown parameter name {name!r}") from None


def kinematic_parts(model: RobotModel, theta: FloatArray) -> tuple[FloatArray, FloatArray]:
    """DH table ``(..., 6, 4)`` [rad, mm] and tool ``(..., 3)`` [mm] for ``theta (..., p)``."""
    dh = model.dh_internal() + theta[..., :N_DH].reshape(*theta.shape[:-1], N_JOINTS, 4)
    tool = model.tool_mm + theta[..., N_DH:N_KIN]
    return dh, tool


def predict_lengths(
    model: RobotModel,
    theta: FloatArray,
    q_rad: FloatArray,
    anchor_index: IndexArray,
    trig: JointTrig | None = None,
) -> FloatArray:
    """Cable lengths predicted by the model.

    Parameters
    ----------
    theta : ndarray, shape (..., p)
        Full parameter vector(s); leading dimensions are parameter-set batches.
    q_rad : ndarray, shape (n, 6)
    anchor_index : ndarray of int, shape (n,)
    trig : tuple of 2 ndarrays, shape (6, n), optional
        :func:`calib.kinematics.joint_trig` of ``q_rad``.

    Returns
    -------
    ndarray, shape (..., n)
        Cable length [mm].
    """
    dh, tool = kinematic_parts(model, theta)
    pos = forward_position(dh, q_rad, tool, model.convention, trig)  # (..., n, 3)
    anchors = theta[..., N_KIN:].reshape(*theta.shape[:-1], -1, 4)  # (..., m, 4)
    sel = anchors[..., anchor_index, :]  # (..., n, 4)
    out: FloatArray = np.linalg.norm(pos - sel[..., :3], axis=-1) + sel[..., 3]
    return out


def length_jacobian(
    model: RobotModel,
    theta: FloatArray,
    q_rad: FloatArray,
    anchor_index: IndexArray,
    trig: JointTrig | None = None,
) -> tuple[FloatArray, FloatArray]:
    """Predicted lengths and their analytic Jacobian with respect to the full parameter vector.

    Shapes as :func:`predict_lengths` (a single parameter vector ``theta``, shape (p,)).

    Returns
    -------
    length_mm : ndarray, shape (n,)
    jac : ndarray, shape (n, p)
        ``∂L/∂theta`` in internal units (mm/rad, mm/mm).
    """
    dh, tool = kinematic_parts(model, theta)
    chain = forward_chain(dh, q_rad, tool, model.convention, trig)
    pos = chain.pos_mm
    anchors = theta[N_KIN:].reshape(-1, 4)
    sel = anchors[anchor_index]
    diff = pos - sel[:, :3]
    dist = np.linalg.norm(diff, axis=1)
    unit = diff / np.maximum(dist, 1e-9)[:, None]
    n = q_rad.shape[0]
    jac = np.zeros((n, theta.shape[0]))
    # ∂L/∂(dh, tool) = uᵀ ∂p/∂(dh, tool); ∂L/∂P0 = −u; ∂L/∂c = 1.
    jac[:, :N_KIN] = projected_jacobian(chain, unit)
    cols = N_KIN + 4 * np.asarray(anchor_index)
    rows = np.arange(n)
    for axis in range(3):
        jac[rows, cols + axis] = -unit[:, axis]
    jac[rows, cols + 3] = 1.0
    return dist + sel[:, 3], jac


def multilaterate(points_mm: FloatArray, length_mm: FloatArray) -> tuple[FloatArray, float]:
    """Closed-form start for the anchor point and zero offset from ``L_i = |p_i − P0| + c``.

    Squaring ``L_i − c = |p_i − P0|`` gives an equation that is linear in
    ``u = (P0, c, |P0|² − c²)``::

        L_i² − |p_i|² = −2 p_i·P0 + 2 L_i c + (|P0|² − c²)

    solved in the least-squares sense (the quadratic link between the unknowns is ignored; the
    nonlinear refinement that follows restores it).

    Parameters
    ----------
    points_mm : ndarray, shape (n, 3)
        Tool positions from the nominal model [mm]; n ≥ 5 and not coplanar.
    length_mm : ndarray, shape (n,)
        Indicator readings [mm].

    Returns
    -------
    p0_mm : ndarray, shape (3,)
    offset_mm : float
    """
    if points_mm.shape[0] < MIN_ANCHOR_SAMPLES:
        raise ValueError(
            f"multilateration needs at least {MIN_ANCHOR_SAMPLES} samples, got {points_mm.shape[0]}"
        )
    a = np.column_stack([-2.0 * points_mm, 2.0 * length_mm, np.ones(points_mm.shape[0])])
    b = length_mm**2 - np.einsum("ij,ij->i", points_mm, points_mm)
    scale = np.maximum(np.linalg.norm(a, axis=0), 1e-12)
    sol, *_ = np.linalg.lstsq(a / scale, b, rcond=1e-12)
    sol = sol / scale
    return sol[:3], float(sol[3])
