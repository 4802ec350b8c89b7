"""The MAP prior's weight (calib.prior): the noise estimate and the options it yields."""

from __future__ import annotations

import numpy as np
import pytest

from calib.cable import N_KIN, ParamLayout
from calib.dataset import make_samples
from calib.identify import IdentifyOptions, identify
from calib.models import builtin_model
from calib.options import PriorOptions, part
from calib.prior import NOISE_RTOL, effective_dof, noise_from_map, scaled_options
from calib.problem import Problem
from calib.synthetic import make_true_cell, random_poses_deg

MODEL = builtin_model("hsr-jr680")


@pytest.mark.parametrize("noise_mm", [0.05, 0.5])
def test_noise_estimate_recovers_the_simulated_noise(noise_mm: float) -> None:
    cell = make_true_cell(MODEL)
    rng = np.random.default_rng(11)
    q = random_poses_deg(cell, 300, rng)
    samples = make_samples(q, cell.lengths_mm(q) + rng.normal(0, noise_mm, 300))
    opts = IdentifyOptions(method="lm", test_fraction=0.0, prior=True)
    block = identify(MODEL, samples, opts).to_json()["prior"]
    assert block["noise_estimated_mm"] == pytest.approx(noise_mm, rel=0.15)
    # The fit ran with the noise of the fixed point: within NOISE_RTOL of what it yields.
    assert block["noise_mm"] == pytest.approx(block["noise_estimated_mm"], rel=NOISE_RTOL)
    assert block["applied"] and 1 <= block["noise_rounds"] <= 4


def test_rejected_rows_do_not_count_in_the_noise() -> None:
    cell = make_true_cell(MODEL)
    rng = np.random.default_rng(2)
    q = random_poses_deg(cell, 50, rng)
    lengths = cell.lengths_mm(q) + rng.normal(0, 0.1, 50)
    lengths[:3] += 30.0
    layout = ParamLayout(("A",))
    free = np.zeros(layout.size, dtype=bool)
    free[N_KIN:] = True
    prob = Problem(MODEL, layout, np.deg2rad(q), lengths, np.zeros(50, int), free, cell.theta)
    x = prob.x0()
    assert noise_from_map(prob, x) > 5.0
    kept = prob.with_weights(np.r_[np.zeros(3), np.ones(47)])
    assert noise_from_map(kept, x) == pytest.approx(0.1, rel=0.3)


def test_scaled_options_scale_the_widths_or_drop_the_prior() -> None:
    base = part(IdentifyOptions(prior=True, prior_mm=2.0, prior_deg=0.2), PriorOptions)
    four = scaled_options(base, 0.3, 4.0)
    assert (four.prior, four.prior_mm, four.prior_deg, four.noise_mm) == (True, 8.0, 0.8, 0.3)
    assert four.prior_weight == "fixed"
    assert not scaled_options(base, 0.3, float("inf")).prior


def test_effective_dof_counts_what_the_data_fit() -> None:
    """Without a prior the data rows use every free parameter; a prior far tighter than the
    data leaves them almost none; the anchor terms, which have no prior, stay counted."""
    cell = make_true_cell(MODEL)
    q = random_poses_deg(cell, 80, np.random.default_rng(4))
    layout = ParamLayout(("A",))
    free = np.zeros(layout.size, dtype=bool)
    free[[1, 5, 9, 14]] = True  # a1 a2 a3 d4
    free[N_KIN:] = True  # P0 and the offset: 4 more
    prob = Problem(
        MODEL, layout, np.deg2rad(q), cell.lengths_mm(q), np.zeros(80, int), free, cell.theta
    )
    assert effective_dof(prob, prob.x0()) == pytest.approx(8.0, abs=1e-6)
    sigma = np.full(layout.size, np.inf)
    sigma[[1, 5, 9, 14]] = 1e-6  # mm: the prior pins the four DH terms
    tight = Problem(
        MODEL,
        layout,
        np.deg2rad(q),
        cell.lengths_mm(q),
        np.zeros(80, int),
        free,
        cell.theta,
        prior_sigma=sigma,
        noise_mm=0.1,
    )
    assert effective_dof(tight, tight.x0()) == pytest.approx(4.0, abs=1e-3)
