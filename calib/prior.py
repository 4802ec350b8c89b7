"""A MAP prior weight that keeps its meaning as the number of samples grows (issue 10, goal 3).

The MAP problem (:mod:`calib.problem`) adds rows ``noise_mm · (x_j − μ_j)/σ_j`` to the data
residuals ``L_model − L``. Its minimiser is the posterior mode only if ``noise_mm`` is the real
1σ of the length residuals. :class:`calib.identify.IdentifyOptions` fixes it at 0.1 mm, while
the bundled data's residuals are 0.2–1 mm: the prior then weighs ``(0.1/σ)² ≈ 1/100`` of what it
should against each sample, and with 2017 rows the data swamp it entirely.

:func:`estimate_noise_mm` estimates ``σ`` from the residuals of a maximum-likelihood fit on the
training rows, ``σ̂ = sqrt(Σ r² / (n − k))`` (the usual unbiased estimate, ``k`` free
parameters), and :func:`map_options` returns the options with ``noise_mm = σ̂``. This is the
empirical-Bayes choice for the noise level; the prior's own widths (``prior_mm``,
``prior_deg``) keep their meaning as plausible DH errors. A model error that the ML fit absorbs
into implausible parameters also lowers ``σ̂``, so the estimate is a lower bound on the noise the
MAP fit will see; :func:`estimate_noise_mm` can iterate (``rounds``) by re-estimating ``σ̂``
from the MAP fit's own residuals, a fixed point of ``σ̂ = rms(r_MAP(σ̂))·sqrt(n/(n − k))``.

Prototype: measured by ``python -m bench.prior_weight`` (grouped hold-out on the bundled data).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from calib.dataset import SampleSet
from calib.identify import IdentifyOptions, identify
from calib.models import RobotModel


def estimate_noise_mm(
    model: RobotModel,
    samples: SampleSet,
    options: IdentifyOptions,
    train_rows: np.ndarray,
    rounds: int = 1,
) -> float:
    """Residual 1σ [mm] of a fit on ``train_rows``: ML first, then ``rounds − 1`` MAP refits.

    ``options`` give the method and prior widths; the test rows are empty in these fits.
    """
    if rounds < 1:
        raise ValueError(f"rounds must be >= 1, got {rounds}")
    if train_rows.size == 0:
        raise ValueError("train_rows: no training rows")
    empty = np.zeros(0, dtype=int)
    opts = replace(options, prior=False)
    sigma = options.noise_mm
    for _ in range(rounds):
        res = identify(model, samples, opts, train_rows=train_rows, test_rows=empty)
        k = len(res.free_names)
        n = int(train_rows.size)
        rms = res.metrics["after"]["train"]["rmse_mm"]
        sigma = float(rms * np.sqrt(n / max(n - k, 1)))
        opts = replace(options, prior=True, noise_mm=sigma)
    return sigma


def map_options(
    model: RobotModel,
    samples: SampleSet,
    options: IdentifyOptions,
    train_rows: np.ndarray,
    rounds: int = 1,
) -> IdentifyOptions:
    """``options`` with the prior on and ``noise_mm`` estimated (:func:`estimate_noise_mm`)."""
    sigma = estimate_noise_mm(model, samples, options, train_rows, rounds)
    return replace(options, prior=True, noise_mm=sigma)
