"""UKF-VSLM, the paper's M9 (Algorithm 1): the UKF's estimate seeds VSLM.

Stage 1 runs :mod:`calib.solvers.ukf` for ``T3`` epochs from the start point (lines 3–15 of
Algorithm 1); stage 2 runs :mod:`calib.solvers.vslm` from ``x_ukf`` (lines 16–21).

Algorithm 1 nests the VSLM update inside a loop over the ``M`` samples (line 18–19), which
would apply eq. (15) ``M`` times per iteration with the same Jacobian of all samples; we read
it as one batch VSLM iteration per ``t``, which is what eq. (15) (a batch Jacobian ``J`` and
residual ``E``) describes and what the complexity ``Θ(T9·M)`` of eq. (26) counts.

**Batch updates in the UKF stage (a speed departure).** Algorithm 1 (lines 6–12) draws sigma
points and updates once per sample. The UKF stage here updates with batches of 1, 2, 4, … up to
32 samples in each epoch (``UKFOptions(batch_size=32, ramp=True)``), ``Y_k`` in eq. (12) being
the batch's "current set of observations": one set of ``2k + 1`` sigma points is propagated
through the kinematics for all samples of a batch in one vectorised call. Under a statistical
linearisation held fixed over the batch, a joint update equals the per-sample sequential
updates, so the two differ only in how often the linearisation is refreshed. The ramp keeps
per-sample refreshes at the start of each epoch, where the covariance is wide (it is reset to
``P_0`` every epoch) and the estimate moves most; fixed batches of 25 from the first sample
sent the real-data MAP fit of one grouped split into a worse local minimum, the ramp does not.
Fewer updates per epoch, the same held-out error on synthetic and real data (the figures:
bench/design_figures.md). The stand-alone ``ukf`` method keeps per-sample updates.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from calib.kinematics import FloatArray
from calib.problem import Problem
from calib.solvers import ukf, vslm
from calib.solvers.common import ProgressFn, SolverResult, report, sub_progress


@dataclass(frozen=True)
class UKFVSLMOptions:
    """Options of both stages."""

    ukf: ukf.UKFOptions = field(default_factory=lambda: ukf.UKFOptions(batch_size=32, ramp=True))
    vslm: vslm.VSLMOptions = field(default_factory=vslm.VSLMOptions)


def solve(
    problem: Problem,
    x0: FloatArray | None = None,
    p0: FloatArray | None = None,
    options: UKFVSLMOptions | None = None,
    progress: ProgressFn | None = None,
    method: str = "ukf-vslm",
) -> SolverResult:
    """Run the cascade; ``p0`` (shape (k, k)) is the UKF's initial covariance."""
    opts = options or UKFVSLMOptions()

    first = ukf.solve(
        problem, x0, p0, opts.ukf, sub_progress(progress, 0.0, 0.5), method=f"{method}/ukf"
    )
    if first.status < 0:
        first.method = method
        return first
    second = vslm.solve(
        problem, first.x, opts.vslm, sub_progress(progress, 0.5, 1.0), method=f"{method}/vslm"
    )
    report(progress, 1.0, f"{method} done")
    return SolverResult(
        method=method,
        x=second.x,
        success=second.success,
        status=second.status,
        message=f"UKF: {first.message}; VSLM: {second.message}",
        iterations=first.iterations + second.iterations,
        cost_history_rms_mm=first.cost_history_rms_mm + second.cost_history_rms_mm[1:],
    )
