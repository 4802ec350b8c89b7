"""Types and helpers shared by every solver (one module per method, one result type)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol, TypeVar, cast

import numpy as np

from calib.kinematics import FloatArray, IndexArray

if TYPE_CHECKING:
    from calib.problem import Evaluation, Problem


class ProgressFn(Protocol):
    """``progress(fraction_done, message, cost_rms_mm=…, iteration=…)``; may raise
    :class:`Cancelled` to stop the solver.

    A solver passes ``cost_rms_mm`` (the data RMS residual [mm], a number) once per whole
    iteration (epoch, generation) it finishes, and only then; :func:`calib.identify.identify`
    numbers those calls 1, 2, … over the whole fit (every stage and robust round) as
    ``iteration``.
    """

    def __call__(
        self,
        fraction: float,
        message: str,
        /,
        *,
        cost_rms_mm: float | None = None,
        iteration: int | None = None,
    ) -> None: ...


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
    fit_starts : list of int
        Index into ``cost_history_rms_mm`` where each fit begins (robust rounds of
        :func:`calib.identify.identify` concatenate theirs; a new fit's cost may rise).
    """

    method: str
    x: FloatArray
    success: bool
    status: int
    message: str
    iterations: int
    cost_history_rms_mm: list[float] = field(default_factory=list)
    elapsed_s: float = 0.0
    fit_starts: list[int] = field(default_factory=lambda: [0])


def column_scale(jac: FloatArray, previous: FloatArray | None = None) -> FloatArray:
    """MINPACK-style column scaling ``D``, shape (k,): the running maximum of column norms.

    Dividing the Jacobian by ``D`` makes the damping term ``λ‖D·dx‖²`` unit-free, which is what
    turns the paper's ``λI`` into a meaningful quantity for mixed mm/rad parameters.
    """
    norms = np.linalg.norm(jac, axis=0)
    norms = np.where(norms > 0, norms, 1.0)
    return norms if previous is None else np.maximum(previous, norms)


@dataclass(frozen=True)
class LinearModel:
    """The Gauss–Newton model of ``½‖r + J h‖²`` in SVD form, without the tall ``U``.

    ``J = U diag(s) Vᵀ`` (thin SVD) is obtained as the SVD of the triangular factor of the QR
    decomposition of ``[J | r]``: with ``[J | r] = Q R``, ``J = Q R₁`` and ``r = Q ρ``, so
    ``R₁ = U₁ diag(s) Vᵀ`` gives the same ``s`` and ``V`` and ``Uᵀ r = U₁ᵀ ρ``. Only ``R``
    (size ``(k+1)²``) is formed; the ``m × k`` SVD of the paper's normal equations is never
    computed, and neither is ``JᵀJ``, whose condition number is the square of ``J``'s.

    Attributes
    ----------
    s : ndarray, shape (r,)
        Singular values, descending (``r = min(m, k)``).
    vt : ndarray, shape (r, k)
    g : ndarray, shape (r,)
        ``Uᵀ r``: the residual's coordinates along the left singular vectors.
    """

    s: FloatArray
    vt: FloatArray
    g: FloatArray

    @classmethod
    def from_jacobian(cls, jac: FloatArray, res: FloatArray) -> LinearModel:
        """Build from ``J`` (shape (m, k)) and ``r`` (shape (m,))."""
        k = jac.shape[1]
        # mode="r" returns the triangular factor only (numpy's stubs type it as a QRResult).
        r_aug = cast(FloatArray, np.linalg.qr(np.column_stack([jac, res]), mode="r"))
        u1, s, vt = np.linalg.svd(r_aug[:, :k], full_matrices=False)
        return cls(s=s, vt=vt, g=u1.T @ r_aug[:, k])

    def step(self, lam: float) -> FloatArray:
        """``h = argmin ‖J h + r‖² + λ‖h‖²``, shape (k,)."""
        coeff = self.s / (self.s * self.s + lam)
        out: FloatArray = -(self.vt.T @ (coeff * self.g))
        return out


def distance_to_optimum_sigma(model: LinearModel, lam: float, cost: float, dof: int) -> float:
    """Distance from the current point to the linearised optimum, in standard errors.

    The λ-damped Gauss–Newton step predicts the cost reduction
    ``ΔL = ½ Σ g_i² (1 − (λ / (s_i² + λ))²)`` (``g = Uᵀ r``). Near the optimum the covariance of
    the estimate is ``σ̂² (JᵀJ)⁻¹`` with ``σ̂² = 2F / dof``, so ``2ΔL/σ̂²`` is (for small λ) the
    squared Mahalanobis length ``hᵀ Cov⁻¹ h`` of the remaining step: how many standard errors
    of the estimate separate the iterate from where the linearised problem puts the optimum.
    Returns ``sqrt(ΔL · dof / F)`` (0 when both are 0, inf when only ``F`` is).

    Parameters
    ----------
    model : LinearModel
        At the current point.
    lam : float
        Damping of the step the test is about (same scaling as ``s²``); directions with
        ``s² ≪ λ`` (numerically null) do not count.
    cost : float
        ``F = ½‖r‖²``.
    dof : int
        Degrees of freedom ``m − k`` (at least 1).
    """
    g, s = model.g, model.s
    damp = lam / (s * s + lam)
    reduction = 0.5 * float(np.sum(g * g * (1.0 - damp * damp)))
    if cost <= 0.0:
        return 0.0 if reduction <= 0.0 else float("inf")
    return float(np.sqrt(max(reduction, 0.0) * max(dof, 1) / cost))


class GaussNewton:
    """The set-up and bookkeeping LM, VSLM and geodesic LM share; they differ in their steps.

    Holds the iterate ``x`` (shape (k,)), its residual ``res`` (m,), Jacobian ``jac`` (m, k)
    and cost ``½‖r‖²`` [mm²], the running column scale ``D`` (k,), the data RMS history [mm]
    and the degrees of freedom ``m − k``. Usage: :meth:`start`; per iteration
    :meth:`linearise`, the stopping test :meth:`within_sigma`, trial steps and
    :meth:`accept`; :meth:`result` at the end.
    """

    def __init__(self, problem: Problem, x0: FloatArray | None, method: str) -> None:
        self.problem = problem
        self.method = method
        self.x = problem.x0() if x0 is None else np.array(x0, dtype=float)
        ev = problem.evaluate(self.x)
        assert ev.jacobian is not None
        self.res, self.jac, self.cost = ev.residual, ev.jacobian, ev.cost
        self.history = [ev.data_rms_mm]
        self.dof = max(problem.n_rows - self.x.shape[0], 1)
        self.scale = column_scale(self.jac)

    def start_failure(self) -> SolverResult | None:
        """The failed result when the start point's residual is not finite, else None."""
        if np.isfinite(self.cost):
            return None
        return SolverResult(
            self.method, self.x, False, -1, "non-finite residual at the start", 0, self.history
        )

    def scaled(self, gtol: float) -> tuple[FloatArray, FloatArray] | None:
        """The scaled Jacobian ``J D⁻¹`` (m, k) and gradient ``(J D⁻¹)ᵀ r`` (k,); None if the
        gradient is below ``gtol ‖r‖`` (converged: the cosine test of MINPACK)."""
        js = self.jac / self.scale
        grad = js.T @ self.res
        if np.max(np.abs(grad)) <= gtol * np.sqrt(2.0 * self.cost):
            return None
        return js, grad

    def linearise(self, gtol: float) -> tuple[LinearModel, FloatArray] | None:
        """The scaled linear model and gradient ``(J D⁻¹)ᵀ r`` (k,); None if that is below
        ``gtol ‖r‖`` (converged)."""
        scaled = self.scaled(gtol)
        if scaled is None:
            return None
        js, grad = scaled
        return LinearModel.from_jacobian(js, self.res), grad

    def within_sigma(self, lin: LinearModel, lam: float, sigma_tol: float) -> str | None:
        """The stop message when within ``sigma_tol`` standard errors of the optimum."""
        distance = distance_to_optimum_sigma(lin, lam, self.cost, self.dof)
        if distance <= sigma_tol:
            return f"within {distance:.2g} standard errors of the optimum (sigma_tol)"
        return None

    def accept(self, x_new: FloatArray, trial: Evaluation) -> None:
        """Move to ``x_new`` whose evaluation is ``trial``; widen the column scale."""
        assert trial.jacobian is not None
        self.x, self.cost, self.res, self.jac = x_new, trial.cost, trial.residual, trial.jacobian
        self.history.append(trial.data_rms_mm)
        self.scale = column_scale(self.jac, self.scale)

    def result(self, status: int, message: str, iterations: int) -> SolverResult:
        return SolverResult(
            method=self.method,
            x=self.x,
            success=status > 0,
            status=status,
            message=message,
            iterations=iterations,
            cost_history_rms_mm=self.history,
        )


#: A solver's stop: status (1 gradient, 2 cost change / statistical test, 3 step) and message.
Stop = tuple[int, str]


class DampingRule(Protocol):
    """What one Gauss–Newton method (LM, VSLM, geodesic LM) adds to :func:`damped_descent`:
    its damping and steps; the loop, the history and the progress are shared."""

    def reference_damping(self, lin: LinearModel) -> float:
        """The damping of the ``sigma_tol`` stopping test (:meth:`GaussNewton.within_sigma`)."""
        ...

    def attempt(
        self, gn: GaussNewton, lin: LinearModel, grad: FloatArray
    ) -> tuple[bool, Stop | None]:
        """Try steps, raising the damping on refusal; accept one (:meth:`GaussNewton.accept`)
        or give up. Returns whether a step was accepted and a stop, if the rule stops here."""
        ...

    def note(self) -> str:
        """Extra words of the iteration's progress message (e.g. ``", step 0.800"``)."""
        ...

    def accepted(self, gn: GaussNewton) -> Stop | None:
        """After an accepted step and its progress report: a stop, if the rule stops here."""
        ...


def damped_descent(
    gn: GaussNewton,
    rule: DampingRule,
    max_iterations: int,
    gtol: float,
    sigma_tol: float,
    progress: ProgressFn | None,
) -> SolverResult:
    """The iteration LM, VSLM and geodesic LM share: per iteration the scaled linear model
    (stop 1 when the gradient is below ``gtol``), the ``sigma_tol`` test (stop 2), the rule's
    damped steps; a refused iteration repeats the last data RMS in the history; one progress
    call per iteration with its data RMS [mm]; stop 3 when no damping decreases the cost."""
    status, message, it = 0, "iteration limit reached", 0
    for it in range(1, max_iterations + 1):
        linear = gn.linearise(gtol)
        if linear is None:
            status, message, it = 1, "gradient below gtol", it - 1
            break
        lin, grad = linear
        stop = gn.within_sigma(lin, rule.reference_damping(lin), sigma_tol)
        if stop is not None:
            status, message, it = 2, stop, it - 1
            break
        accepted, stop_now = rule.attempt(gn, lin, grad)
        if not accepted:
            gn.history.append(gn.history[-1])
        report(
            progress,
            it / max_iterations,
            f"{gn.method} iteration {it}{rule.note()}, rms {gn.history[-1]:.4f} mm",
            gn.history[-1],
        )
        if stop_now is None and not accepted:
            stop_now = 3, "no decrease possible at any damping (converged to precision)"
        if stop_now is None:
            stop_now = rule.accepted(gn)
        if stop_now is not None:
            status, message = stop_now
            break
    return gn.result(status, message, it)


def sample_batches(
    n: int, size: int, rng: np.random.Generator | None = None, ramp: bool = False
) -> list[IndexArray]:
    """Row indices of ``n`` samples in batches of ``size`` (shuffled first if ``rng``).

    With ``ramp`` the batches grow 1, 2, 4, … up to ``size``: the first updates, while the
    filter's covariance is still wide and the estimate moves most, take one sample each.
    """
    order = np.arange(n) if rng is None else rng.permutation(n)
    out: list[IndexArray] = []
    start, step = 0, 1 if ramp else size
    while start < n:
        out.append(order[start : start + step])
        start += step
        step = min(2 * step, size)
    return out


#: One filter update of :func:`run_epochs`: ``(x, p, rows, r_var) -> (x_new, p_new)`` from the
#: estimate ``x`` (k,) and the predicted covariance ``p`` (k, k) (``Q`` added) with the samples
#: ``rows`` (b,) of weight > 0 and their measurement variances ``r_var`` (b,) [mm²].
FilterUpdate = Callable[
    [FloatArray, FloatArray, IndexArray, FloatArray], tuple[FloatArray, FloatArray]
]


def run_epochs(
    problem: Problem,
    x: FloatArray,
    p0: FloatArray,
    epochs: int,
    process_noise: float,
    batches: list[IndexArray],
    update: FilterUpdate,
    progress: ProgressFn | None,
    method: str,
    note_every: int | None = None,
) -> SolverResult:
    """The epoch loop the EKF and the UKF share: per epoch the covariance restarts at ``p0``
    (k, k); per batch the rows of weight 0 are skipped, ``Q = process_noise · p0`` is added
    and ``update`` moves the estimate; the data RMS after each epoch [mm] is the history and
    the progress. Status -1 (the last good estimate) on a non-finite update, else 4 after
    ``epochs`` epochs. ``note_every``: also a progress message every that many batches."""
    noise_var = problem.noise_mm**2
    q = process_noise * p0
    history = [problem.data_rms_mm(x)]
    total = epochs * len(batches)
    done = 0
    for epoch in range(epochs):
        p = p0.copy()
        for rows in batches:
            weights = problem.weights[rows]
            keep = weights > 0
            done += 1
            if not np.any(keep):
                continue
            rows, weights = rows[keep], weights[keep]
            p = p + q
            x_new, p_new = update(x, p, rows, noise_var / weights)
            if not np.all(np.isfinite(x_new)):
                return SolverResult(
                    method, x, False, -1, f"non-finite update in epoch {epoch + 1}", epoch, history
                )
            x, p = x_new, p_new
            if note_every and done % note_every == 0:
                report(progress, done / total, f"{method} epoch {epoch + 1}")
        history.append(problem.data_rms_mm(x))
        report(
            progress,
            (epoch + 1) / epochs,
            f"{method} epoch {epoch + 1} done, rms {history[-1]:.4f} mm",
            history[-1],
        )
    return SolverResult(
        method=method,
        x=x,
        success=True,
        status=4,
        message=f"{epochs} epochs done",
        iterations=epochs,
        cost_history_rms_mm=history,
    )


def report(
    progress: ProgressFn | None, fraction: float, message: str, cost_rms_mm: float | None = None
) -> None:
    """Call ``progress`` (if any) with the fraction clipped to 0–1; ``cost_rms_mm`` [mm] only
    at the end of a whole iteration (see :class:`ProgressFn`)."""
    if progress is not None:
        cost = None if cost_rms_mm is None else float(cost_rms_mm)
        progress(min(max(fraction, 0.0), 1.0), message, cost_rms_mm=cost)


def sub_progress(progress: ProgressFn | None, lo: float, hi: float) -> ProgressFn | None:
    """``progress`` for one stage of a solver: fractions 0–1 mapped onto ``lo``–``hi``."""
    if progress is None:
        return None
    outer = progress

    def stage(
        f: float, msg: str, /, *, cost_rms_mm: float | None = None, iteration: int | None = None
    ) -> None:
        outer(lo + (hi - lo) * f, msg, cost_rms_mm=cost_rms_mm, iteration=iteration)

    return stage


_O = TypeVar("_O")
_O_contra = TypeVar("_O_contra", contravariant=True)


class GaussNewtonSolve(Protocol[_O_contra]):
    """The public ``solve`` of a Gauss–Newton solver (:func:`gauss_newton_solver`)."""

    def __call__(
        self,
        problem: Problem,
        x0: FloatArray | None = None,
        options: _O_contra | None = None,
        progress: ProgressFn | None = None,
        method: str = ...,
    ) -> SolverResult: ...


def gauss_newton_solver(
    default_options: Callable[[], _O], default_method: str
) -> Callable[[Callable[[GaussNewton, _O, ProgressFn | None], SolverResult]], GaussNewtonSolve[_O]]:
    """The preamble LM and VSLM share, in one place: ``solve(problem, x0=None, options=None,
    progress=None, method=default_method)`` takes the default options, evaluates the start
    point (``problem.x0()`` unless ``x0``, shape (k,)) in a :class:`GaussNewton`, returns its
    failed result when the start residual is not finite, and otherwise runs the decorated
    ``body(gn, opts, progress)`` (``gn.problem`` and ``gn.method`` are the arguments)."""

    def wrap(
        body: Callable[[GaussNewton, _O, ProgressFn | None], SolverResult],
    ) -> GaussNewtonSolve[_O]:
        def solve(
            problem: Problem,
            x0: FloatArray | None = None,
            options: _O | None = None,
            progress: ProgressFn | None = None,
            method: str = default_method,
        ) -> SolverResult:
            opts = default_options() if options is None else options
            gn = GaussNewton(problem, x0, method)
            failed = gn.start_failure()
            return failed if failed is not None else body(gn, opts, progress)

        # The body's name and docstring, but the signature of the public solve (no __wrapped__).
        for name in ("__module__", "__name__", "__qualname__", "__doc__"):
            setattr(solve, name, getattr(body, name))
        return solve

    return wrap
