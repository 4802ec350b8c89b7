"""The least-squares problem every solver works on.

Residual (model minus measurement, so that the Jacobian is ``∂L_model/∂x``)::

    r_i(x)       = sqrt(w_i) · (L_model(q_i; θ(x)) − L_i)              i = 1..n   [mm]
    r_{n+j}(x)   = noise_mm · (x_j − μ_j) / σ_j                        (MAP prior rows, optional)

``x`` (shape ``(k,)``) is the vector of *free* parameters; :meth:`Problem.full` scatters it into
the full vector ``θ`` (shape ``(p,)``, see :mod:`calib.cable`), the other entries staying at
``theta0``. ``w_i`` are robust weights (1 by default). With the prior rows the minimiser is the
MAP estimate under Gaussian noise of ``noise_mm`` and a Gaussian prior ``N(μ, σ²)`` on each
free parameter.

With a drift basis ``B`` (shape ``(n, m)``, :mod:`calib.drift`) the data rows carry ``m``
nuisance terms ``B β`` more; being linear and independent of ``θ`` they are profiled out
(variable projection): the weighted data residual and Jacobian are projected onto the
complement of ``span(√w · B)``, so every solver works on the robot's parameters only.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import cached_property

import numpy as np
from numpy.typing import NDArray

from calib.cable import ParamLayout, length_jacobian, predict_lengths
from calib.kinematics import FloatArray, IndexArray, JointTrig, joint_trig
from calib.linalg import coefficients, orthonormal
from calib.models import RobotModel
from calib.options import IDENTIFY_NOISE_MM

BoolArray = NDArray[np.bool_]


@dataclass(frozen=True)
class Evaluation:
    """The residual (and optionally its Jacobian) at one point, from a single model pass.

    Attributes
    ----------
    residual : ndarray, shape (n,) or (n + k,)
        Weighted data residuals, then the prior rows if any [mm].
    jacobian : ndarray, shape (n[+k], k) or None
    cost : float
        ``0.5 · Σ r²`` [mm²].
    data_rms_mm : float
        Unweighted RMS of the data residuals ``L_model − L`` [mm].
    """

    residual: FloatArray
    jacobian: FloatArray | None
    cost: float
    data_rms_mm: float


@dataclass(frozen=True)
class Problem:
    """Data, free-parameter mask, weights and prior of one identification.

    Attributes
    ----------
    q_rad : ndarray, shape (n, 6)
        Joint angles [rad].
    length_mm : ndarray, shape (n,)
        Measured cable lengths [mm].
    anchor_index : ndarray of int, shape (n,)
    free : ndarray of bool, shape (p,)
    theta0 : ndarray, shape (p,)
        Starting point; the values of fixed parameters.
    weights : ndarray, shape (n,)
        Robust weights in [0, 1].
    prior_sigma : ndarray, shape (p,) or None
        Prior standard deviation per parameter (internal units); None = no prior (ML).
    prior_mean : ndarray, shape (p,)
    noise_mm : float
        Assumed 1σ measurement noise, used to weigh the prior rows [mm].
    """

    model: RobotModel
    layout: ParamLayout
    q_rad: FloatArray
    length_mm: FloatArray
    anchor_index: IndexArray
    free: BoolArray
    theta0: FloatArray
    weights: FloatArray = field(default_factory=lambda: np.ones(0))
    prior_sigma: FloatArray | None = None
    prior_mean: FloatArray | None = None
    noise_mm: float = IDENTIFY_NOISE_MM
    drift_basis: FloatArray | None = None

    def __post_init__(self) -> None:
        n = self.q_rad.shape[0]
        if self.weights.shape[0] == 0:
            object.__setattr__(self, "weights", np.ones(n))
        if self.prior_sigma is not None and self.prior_mean is None:
            object.__setattr__(self, "prior_mean", self.theta0.copy())

    # ----------------------------------------------------------------- shapes and mapping
    @property
    def n_samples(self) -> int:
        return int(self.q_rad.shape[0])

    @property
    def n_free(self) -> int:
        return int(np.count_nonzero(self.free))

    @property
    def free_names(self) -> list[str]:
        return [n for n, f in zip(self.layout.names, self.free, strict=True) if f]

    @property
    def has_prior(self) -> bool:
        return self.prior_sigma is not None

    def x0(self) -> FloatArray:
        """Free part of ``theta0``, shape (k,)."""
        return np.asarray(self.theta0[self.free], dtype=float)

    def full(self, x: FloatArray) -> FloatArray:
        """Scatter free values ``x`` (shape ``(..., k)``) into full vectors ``(..., p)``."""
        x = np.asarray(x, dtype=float)
        out = np.broadcast_to(self.theta0, (*x.shape[:-1], self.theta0.shape[0])).copy()
        out[..., self.free] = x
        return out

    def with_weights(self, weights: FloatArray) -> Problem:
        return replace(self, weights=np.asarray(weights, dtype=float))

    def with_theta0(self, theta0: FloatArray) -> Problem:
        return replace(self, theta0=np.asarray(theta0, dtype=float))

    @cached_property
    def sqrt_weights(self) -> FloatArray:
        """``sqrt(w)``, shape (n,)."""
        return np.sqrt(self.weights)

    @cached_property
    def drift_q(self) -> FloatArray | None:
        """Orthonormal basis (n, r) of ``span(√w · B)``, or None without a drift basis."""
        if self.drift_basis is None or self.drift_basis.shape[1] == 0:
            return None
        return orthonormal(self.sqrt_weights[:, None] * self.drift_basis)

    @property
    def n_drift(self) -> int:
        """Nuisance columns profiled out (the rank of the weighted drift basis)."""
        q = self.drift_q
        return 0 if q is None else int(q.shape[1])

    def project(self, rows: FloatArray) -> FloatArray:
        """Weighted data rows (n,) or (n, k) with the drift basis projected out."""
        q = self.drift_q
        if q is None:
            return rows
        out: FloatArray = rows - q @ (q.T @ rows)
        return out

    def drift_coefficients(self, x: FloatArray) -> FloatArray:
        """``β`` (m,) [mm]: the drift terms that best explain the data at ``x`` (shape (k,))."""
        if self.drift_basis is None:
            return np.zeros(0)
        sw = self.sqrt_weights
        return coefficients(sw[:, None] * self.drift_basis, sw * (self.length_mm - self.predict(x)))

    @cached_property
    def trig(self) -> JointTrig:
        """``cos``/``sin`` of the joint angles, each (6, n), computed once per problem."""
        return joint_trig(self.q_rad)

    def _trig_rows(self, rows: IndexArray | slice) -> JointTrig:
        c, s = self.trig
        return c[:, rows], s[:, rows]

    @cached_property
    def n_rows(self) -> int:
        """Rows that carry information: non-zero-weight samples plus the prior rows."""
        return int(np.count_nonzero(self.weights > 0)) + (self.n_free if self.has_prior else 0)

    # ---------------------------------------------------------------- model evaluations
    def evaluate(self, x: FloatArray, jacobian: bool = True) -> Evaluation:
        """Residual, optional Jacobian, cost and data RMS at ``x`` (shape (k,)), in one pass."""
        if jacobian:
            pred, jac_full = length_jacobian(
                self.model, self.full(x), self.q_rad, self.anchor_index, self.trig
            )
            jac: FloatArray | None = self.sqrt_weights[:, None] * jac_full[:, self.free]
        else:
            pred, jac = self.predict(x), None
        raw = pred - self.length_mm
        res = self.project(self.sqrt_weights * raw)
        if jac is not None:
            jac = self.project(jac)
        if self.drift_q is not None:
            raw = res / np.where(self.sqrt_weights > 0, self.sqrt_weights, 1.0)
        if self.has_prior:
            pres, pjac = self._prior_rows(x)
            res = np.concatenate([res, pres])
            if jac is not None:
                jac = np.vstack([jac, pjac])
        return Evaluation(
            residual=res,
            jacobian=jac,
            cost=0.5 * float(res @ res),
            data_rms_mm=float(np.sqrt(np.mean(raw * raw))),
        )

    def predict(self, x: FloatArray, rows: IndexArray | slice = slice(None)) -> FloatArray:
        """Model lengths [mm] for free vector(s) ``x`` (``(k,)`` or ``(S, k)``) at ``rows``.

        Returns shape ``(len(rows),)`` or ``(S, len(rows))``.
        """
        return predict_lengths(
            self.model,
            self.full(x),
            self.q_rad[rows],
            self.anchor_index[rows],
            self._trig_rows(rows),
        )

    def _prior_rows(self, x: FloatArray) -> tuple[FloatArray, FloatArray]:
        assert self.prior_sigma is not None and self.prior_mean is not None
        sig = self.prior_sigma[self.free]
        scale = self.noise_mm / sig
        res = scale * (x - self.prior_mean[self.free])
        return res, np.diag(scale)

    def residuals(self, x: FloatArray) -> FloatArray:
        """Stacked residual vector, shape (n,) or (n + k,) with the prior [mm]."""
        data = self.project(self.sqrt_weights * (self.predict(x) - self.length_mm))
        if not self.has_prior:
            return data
        return np.concatenate([data, self._prior_rows(x)[0]])

    def residuals_and_jacobian(self, x: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Residual (see :meth:`residuals`) and its Jacobian, shape (n[+k], k)."""
        ev = self.evaluate(x)
        assert ev.jacobian is not None
        return ev.residual, ev.jacobian

    def cost(self, x: FloatArray) -> float:
        """``0.5 · Σ r²`` [mm²]."""
        r = self.residuals(x)
        return 0.5 * float(r @ r)

    def data_rms_mm(self, x: FloatArray) -> float:
        """Unweighted RMS of the data residuals [mm] (no prior rows)."""
        r = self.predict(x) - self.length_mm
        if self.drift_q is not None:
            sw = self.sqrt_weights
            r = self.project(sw * r) / np.where(sw > 0, sw, 1.0)
        return float(np.sqrt(np.mean(r * r)))
