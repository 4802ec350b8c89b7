"""Verify: a second campaign of the same true robot is predicted to about the noise level; a
moved sensor needs ``refit_anchor``."""

from __future__ import annotations

import csv
import io
import json
from typing import Any

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calib.dataset import make_samples
from calib.identify import IdentifyOptions, identify
from calib.models import RobotModel, builtin_model
from calib.synthetic import TrueCell, make_true_cell, noisy_lengths, random_poses_deg
from calib.tcp import aligned_position_error_mm
from calib.verify import VerifyOptions, aligned_rms_mm, verify

NOISE_MM = 0.05


@pytest.fixture(scope="module")
def nominal() -> RobotModel:
    return builtin_model("hsr-jr680")


@pytest.fixture(scope="module")
def identified(nominal: RobotModel) -> tuple[TrueCell, dict[str, Any]]:
    cell = make_true_cell(nominal)
    rng = np.random.default_rng(31)
    q = random_poses_deg(cell, 100, rng)
    samples = make_samples(q, noisy_lengths(cell, q, rng, noise_mm=NOISE_MM))
    return cell, identify(nominal, samples, IdentifyOptions(test_fraction=0.2)).to_json()


def _campaign(cell: TrueCell, seed: int, n: int = 100) -> Any:
    rng = np.random.default_rng(seed)
    q = random_poses_deg(cell, n, rng)
    return make_samples(q, noisy_lengths(cell, q, rng, noise_mm=NOISE_MM))


def test_second_campaign_rmse_is_near_the_noise(
    identified: tuple[TrueCell, dict[str, Any]],
) -> None:
    cell, result = identified
    out = verify(result, _campaign(cell, 32), VerifyOptions(max_rmse_mm=0.1))
    print(f"second campaign: RMSE {out.metrics['rmse_mm']:.4f} mm (σ {NOISE_MM} mm)")
    assert 0.7 * NOISE_MM < out.metrics["rmse_mm"] < 1.6 * NOISE_MM
    assert out.passed is True
    assert out.reference_rmse_mm is not None and out.reference_rmse_mm < 0.1
    strict = verify(result, _campaign(cell, 32), VerifyOptions(max_rmse_mm=0.01))
    assert strict.passed is False


def test_moved_anchor_needs_refit(
    nominal: RobotModel, identified: tuple[TrueCell, dict[str, Any]]
) -> None:
    cell, result = identified
    moved = make_true_cell(
        nominal, anchors_mm=np.array([[1100.0, -400.0, 600.0]]), offsets_mm=np.array([-120.0])
    )
    np.testing.assert_array_equal(moved.theta[:27], cell.theta[:27])  # same robot, same hook
    samples = _campaign(moved, 33)
    plain = verify(result, samples)
    refit = verify(result, samples, VerifyOptions(refit_anchor=True))
    print(
        f"moved anchor: plain RMSE {plain.metrics['rmse_mm']:.2f} mm, refit "
        f"{refit.metrics['rmse_mm']:.4f} mm"
    )
    assert plain.metrics["rmse_mm"] > 50 * NOISE_MM
    assert 0.7 * NOISE_MM < refit.metrics["rmse_mm"] < 1.6 * NOISE_MM
    np.testing.assert_allclose(refit.anchors["A"]["anchor_mm"], [1100.0, -400.0, 600.0], atol=2.0)
    assert refit.anchors["A"]["refit"] is True and plain.anchors["A"]["refit"] is False


def test_unknown_anchor_and_outputs(identified: tuple[TrueCell, dict[str, Any]]) -> None:
    cell, result = identified
    samples = _campaign(cell, 34, n=20)
    other = make_samples(samples.joints_deg, samples.length_mm, anchor=["B"] * 20)
    with pytest.raises(ValueError, match="anchor"):
        verify(result, other)
    out = verify(result, samples)
    rows = list(csv.DictReader(io.StringIO(out.to_csv())))
    assert len(rows) == 20
    np.testing.assert_allclose([float(r["residual_mm"]) for r in rows], out.residual_mm)
    np.testing.assert_allclose(out.measured_mm - out.predicted_mm, out.residual_mm)
    doc = json.loads(json.dumps(out.to_json()))
    assert doc["metrics"]["n"] == 20 and len(doc["residuals"]) == 20
    with pytest.raises(ValueError, match="max_rmse_mm"):
        VerifyOptions(max_rmse_mm=-1.0)


def test_rigid_align_recovers_a_rigid_motion() -> None:
    rng = np.random.default_rng(35)
    pts = rng.uniform(-1000, 1000, size=(50, 3))
    rot = Rotation.from_rotvec([0.1, -0.2, 0.3])
    moved = rot.apply(pts) + np.array([10.0, -5.0, 2.0])
    res = aligned_position_error_mm(pts, moved)
    assert res.shape == (50,) and res.max() < 1e-9
    noisy = moved + rng.normal(0, 0.1, size=moved.shape)
    assert 0.1 < aligned_rms_mm(pts, noisy) < 0.2  # 3-D noise of 0.1 mm per axis: ~0.17
    with pytest.raises(ValueError, match="points_mm"):
        aligned_position_error_mm(pts[:, :2], moved[:, :2])
