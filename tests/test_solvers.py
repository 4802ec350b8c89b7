"""Numerical building blocks of the solvers and their stopping rules."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from calib.dataset import make_samples
from calib.identify import IdentifyOptions, identify
from calib.models import builtin_model
from calib.solvers.common import LinearModel, distance_to_optimum_sigma, sample_batches
from calib.synthetic import make_true_cell, random_poses_deg

MODEL = builtin_model("hsr-jr680")


def test_linear_model_matches_the_svd_of_the_jacobian_and_the_damped_solution() -> None:
    rng = np.random.default_rng(1)
    jac = rng.normal(size=(60, 8)) * np.logspace(0, 4, 8)  # badly scaled columns
    res = rng.normal(size=60)
    lin = LinearModel.from_jacobian(jac, res)
    np.testing.assert_allclose(lin.s, np.linalg.svd(jac, compute_uv=False), rtol=1e-10)
    u, _, _ = np.linalg.svd(jac, full_matrices=False)
    np.testing.assert_allclose(np.abs(lin.g), np.abs(u.T @ res), rtol=1e-8)  # signs may differ
    lam = 1e-3 * lin.s[0] ** 2
    # argmin ‖J h + r‖² + λ‖h‖²: the stacked least-squares problem [J; √λ I] h = [−r; 0].
    stacked = np.vstack([jac, np.sqrt(lam) * np.eye(8)])
    expected, *_ = np.linalg.lstsq(stacked, np.r_[-res, np.zeros(8)], rcond=None)
    np.testing.assert_allclose(lin.step(lam), expected, rtol=1e-8, atol=1e-12)
    # Undamped: the Gauss–Newton step.
    gn, *_ = np.linalg.lstsq(jac, -res, rcond=None)
    np.testing.assert_allclose(lin.step(0.0), gn, rtol=1e-8)


def test_distance_to_optimum_is_the_mahalanobis_length_of_the_remaining_step() -> None:
    """Linear problem r(x) = J x − y: closed form (x − x*)ᵀ JᵀJ (x − x*) · dof / (2F)."""
    rng = np.random.default_rng(2)
    jac = rng.normal(size=(50, 5))
    y = jac @ rng.normal(size=5) + rng.normal(0, 0.1, 50)
    x_opt, *_ = np.linalg.lstsq(jac, y, rcond=None)
    x = x_opt + rng.normal(0, 0.05, 5)
    res = jac @ x - y
    cost = 0.5 * float(res @ res)
    dof = 50 - 5
    d = x - x_opt
    expected = np.sqrt(d @ jac.T @ jac @ d * dof / (2 * cost))
    got = distance_to_optimum_sigma(LinearModel.from_jacobian(jac, res), 0.0, cost, dof)
    assert got == pytest.approx(expected, rel=1e-8)
    # At the optimum the distance is zero; with no residual at all too.
    res_opt = jac @ x_opt - y
    lin_opt = LinearModel.from_jacobian(jac, res_opt)
    assert distance_to_optimum_sigma(lin_opt, 0.0, 0.5 * float(res_opt @ res_opt), dof) < 1e-6
    zero = LinearModel.from_jacobian(jac, np.zeros(50))
    assert distance_to_optimum_sigma(zero, 0.0, 0.0, dof) == 0.0


@pytest.mark.parametrize(("n", "size"), [(100, 32), (7, 32), (50, 1), (64, 8)])
def test_ramped_batches_cover_every_sample_once_growing_to_the_size(n: int, size: int) -> None:
    batches = sample_batches(n, size, ramp=True)
    np.testing.assert_array_equal(np.concatenate(batches), np.arange(n))
    sizes = [b.size for b in batches]
    assert sizes[0] == 1
    assert all(s <= size for s in sizes)
    assert all(b <= a * 2 for a, b in itertools.pairwise(sizes))
    assert [b.size for b in sample_batches(n, size)][:-1] == [size] * (len(range(0, n, size)) - 1)


@pytest.fixture(scope="module")
def noisy_case() -> tuple[np.ndarray, np.ndarray]:
    cell = make_true_cell(MODEL)
    rng = np.random.default_rng(31)
    q = random_poses_deg(cell, 150, rng)
    lengths = cell.lengths_mm(q) + rng.normal(0, 0.05, 150)
    return q, lengths


def test_vslm_and_lm_stop_by_the_sigma_test_at_the_same_optimum(noisy_case) -> None:
    q, lengths = noisy_case
    samples = make_samples(q, lengths)
    train, test = np.arange(120), np.arange(120, 150)
    results = {
        m: identify(MODEL, samples, IdentifyOptions(method=m), train_rows=train, test_rows=test)  # type: ignore[arg-type]
        for m in ("lm", "vslm", "ukf-vslm")
    }
    for m, res in results.items():
        assert res.solver.status == 2, (m, res.solver.message)
        assert "standard errors" in res.solver.message, m
    lm_theta = results["lm"].theta
    idx = [results["lm"].layout.index(n) for n in results["lm"].free_names]
    sigma = results["lm"].sigma[idx]
    for m in ("vslm", "ukf-vslm"):
        assert results[m].free_names == results["lm"].free_names
        z = (results[m].theta[idx] - lm_theta[idx]) / sigma
        assert np.max(np.abs(z)) < 0.01, (m, float(np.max(np.abs(z))))


def test_vslm_from_the_ukf_seed_needs_few_iterations(noisy_case) -> None:
    """Regression: with λ₀ at 1e-6 s²_max VSLM needed ~35 iterations (two directions at
    s² ≈ 6e-7 s²_max converged at the rate s²/(s² + λ) instead of 1 − δ); now under 15."""
    q, lengths = noisy_case
    samples = make_samples(q, lengths)
    res = identify(
        MODEL, samples, IdentifyOptions(), train_rows=np.arange(120), test_rows=np.arange(120, 150)
    )
    vslm_iterations = res.solver.iterations - IdentifyOptions().ukf_epochs
    assert vslm_iterations <= 15, res.solver.message
