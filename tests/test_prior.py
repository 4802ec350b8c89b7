"""The MAP noise weight estimated from the residuals (calib.prior)."""

from __future__ import annotations

import numpy as np
import pytest

from calib.dataset import make_samples
from calib.identify import IdentifyOptions
from calib.models import builtin_model
from calib.prior import estimate_noise_mm, map_options
from calib.synthetic import make_true_cell, random_poses_deg

MODEL = builtin_model("hsr-jr680")


@pytest.mark.parametrize("noise_mm", [0.05, 0.5])
def test_noise_estimate_recovers_the_simulated_noise(noise_mm: float) -> None:
    cell = make_true_cell(MODEL)
    rng = np.random.default_rng(11)
    q = random_poses_deg(cell, 300, rng)
    samples = make_samples(q, cell.lengths_mm(q) + rng.normal(0, noise_mm, 300))
    opts = IdentifyOptions(method="lm", test_fraction=0.0)
    sigma = estimate_noise_mm(MODEL, samples, opts, np.arange(300))
    assert sigma == pytest.approx(noise_mm, rel=0.15)
    mapped = map_options(MODEL, samples, opts, np.arange(300))
    assert mapped.prior and mapped.noise_mm == pytest.approx(sigma)


def test_bad_arguments_are_named() -> None:
    cell = make_true_cell(MODEL)
    q = random_poses_deg(cell, 40, np.random.default_rng(1))
    samples = make_samples(q, cell.lengths_mm(q))
    with pytest.raises(ValueError, match="rounds"):
        estimate_noise_mm(MODEL, samples, IdentifyOptions(), np.arange(40), rounds=0)
    with pytest.raises(ValueError, match="train_rows"):
        estimate_noise_mm(MODEL, samples, IdentifyOptions(), np.zeros(0, dtype=int))
