"""Types and helpers shared by every solver (one module per method, one result type)."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from calib.kinematics import FloatArray, IndexArray

#: ``progress(fraction_done, message)``; may raise :class:`Cancelled` to stop the solver.
ProgressFn = Callable[[float, str], None]


class Cancelled(Exception):
    """Raised by a progress callback to stop a running identification."""


@dataclass
class SolverResult:
    """Outcome of one solver run.

    Attributes
    ----------
    x : ndarray, shape (k,)
        Free parameters at the end (internal units: mm, rad).
    success : bool
        True when a convergence test was met (``status`` > 0).
    status : int
        1 gradient small, 2 cost change small, 3 step small, 4 fixed budget done (filters, DE),
        0 iteration limit reached, -1 numerical failure (the last good iterate is returned).
    message : str
    iterations : int
    cost_history_rms_mm : list of float
        Data RMS residual [mm] after each iteration (index 0 = start).
    elapsed_s : float
    """

    method: str
    x: FloatArray
    success: bool
    status: int
    message: str
    iterations: int
    cost_history_rms_mm: list[float] = field(default_factory=list)
    elapsed_s: float = 0.0


class Timer:
    """Wall-clock timer for ``elapsed_s``."""

    def __init__(self) -> None:
        self.start = time.perf_counter()

    def elapsed(self) -> float:
        return time.perf_counter() - self.start


def column_scale(jac: FloatArray, previous: FloatArray | None = None) -> FloatArray:
    """MINPACK-style column scaling ``D``, shape (k,): the running maximum of column norms.

    Dividing the Jacobian by ``D`` makes the damping term ``λ‖D·dx‖²`` unit-free, which is what
    turns the paper's ``λI`` into a meaningful quantity for mixed mm/rad parameters.
    """
    norms = np.linalg.norm(jac, axis=0)
    norms = np.where(norms > 0, norms, 1.0)
    return norms if previous is None else np.maximum(previous, norms)


def damped_step(
    u: FloatArray, s: FloatArray, vt: FloatArray, res: FloatArray, lam: float
) -> FloatArray:
    """Solve ``min ‖J h + r‖² + λ‖h‖²`` from the thin SVD ``J = U diag(s) Vᵀ``.

    Working from the SVD (never forming ``JᵀJ``) keeps the step finite for condition numbers
    far beyond 1e8, where the normal equations of the paper's eq. (14) lose all digits.
    Returns ``h``, shape (k,).
    """
    coeff = s / (s * s + lam)
    out: FloatArray = -(vt.T @ (coeff * (u.T @ res)))
    return out


def sample_batches(n: int, size: int, rng: np.random.Generator | None = None) -> list[IndexArray]:
    """Row indices of ``n`` samples in batches of ``size`` (shuffled first if ``rng``)."""
    order = np.arange(n) if rng is None else rng.permutation(n)
    return [order[i : i + size] for i in range(0, n, size)]


def report(progress: ProgressFn | None, fraction: float, message: str) -> None:
    if progress is not None:
        progress(min(max(fraction, 0.0), 1.0), message)
