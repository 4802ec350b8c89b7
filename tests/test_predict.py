"""calib.predict reproduces the identify result's own predictions from its JSON."""

from __future__ import annotations

import numpy as np

from calib.dataset import make_samples
from calib.identify import IdentifyOptions, identify
from calib.models import builtin_model
from calib.predict import predict_lengths_from_result
from calib.synthetic import make_true_cell, noisy_lengths, random_poses_deg


def test_prediction_from_result_json_matches_the_truth() -> None:
    rng = np.random.default_rng(7)
    model = builtin_model("hsr-jr680")
    cell = make_true_cell(model)
    q = random_poses_deg(cell, 80, rng)
    samples = make_samples(q, noisy_lengths(cell, q, rng, noise_mm=0.0))
    # Rank threshold only, so noise-free data are fitted exactly (noise_rank would fix
    # joint-5 terms and leave a trace of ~1 µm).
    opts = IdentifyOptions(method="lm", test_fraction=0.0, noise_rank=False)
    result = identify(model, samples, opts).to_json()
    q_new = random_poses_deg(cell, 20, rng)
    pred = predict_lengths_from_result(result, q_new)
    assert np.abs(pred - cell.lengths_mm(q_new)).max() < 1e-3
