"""``tcp_uncertainty_mm`` in result.json: the fit's covariance propagated to the tool point."""

from __future__ import annotations

import json
from typing import Any

import numpy as np

from calib.cable import kinematic_parts
from calib.dataset import make_samples
from calib.identify import IdentifyOptions, identify
from calib.kinematics import forward_position
from calib.models import builtin_model
from calib.synthetic import make_true_cell, random_poses_deg
from calib.tcp import aligned_position_error_mm, workspace_sample_deg

MODEL = builtin_model("hsr-jr680")
NOISE_MM = 0.05


def _fit(n: int, seed: int) -> tuple[dict[str, Any], float]:
    """result.json of an LM fit on ``n`` noisy poses of a virtual cell, and the RMS aligned
    tool-point error [mm] of the fit against the cell's truth at 300 workspace poses."""
    cell = make_true_cell(MODEL)
    rng = np.random.default_rng(seed)
    q = random_poses_deg(cell, n, rng)
    lengths = cell.lengths_mm(q) + rng.normal(0.0, NOISE_MM, n)
    res = identify(MODEL, make_samples(q, lengths), IdentifyOptions(method="lm", test_fraction=0))
    data = json.loads(json.dumps(res.to_json(), allow_nan=True))
    ws = np.deg2rad(workspace_sample_deg(MODEL, 300, seed=5))
    positions = []
    for model, theta in ((res.model, res.theta), (MODEL, cell.theta)):
        dh, tool = kinematic_parts(model, theta)
        positions.append(forward_position(dh, ws, tool, MODEL.convention))
    err = aligned_position_error_mm(*positions)
    return data, float(np.sqrt(np.mean(err**2)))


def test_result_json_has_tcp_uncertainty_and_it_predicts_the_error() -> None:
    small, err_small = _fit(60, seed=3)
    large, _ = _fit(240, seed=3)
    tcp = small["tcp_uncertainty_mm"]
    assert set(tcp) == {"rms", "max"}
    assert 0.0 < tcp["rms"] <= tcp["max"]
    # Four times the poses: about half the σ (1/sqrt(4)), not the same, not a quarter.
    ratio = tcp["rms"] / large["tcp_uncertainty_mm"]["rms"]
    assert 1.5 < ratio < 2.8, ratio
    # The prediction is the expected aligned error: the real one is of the same size.
    assert tcp["rms"] / 3.0 < err_small < 3.0 * tcp["rms"], (err_small, tcp)
