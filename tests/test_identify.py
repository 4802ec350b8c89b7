"""Identification against known truth: the issue's acceptance cases."""

from __future__ import annotations

import numpy as np
import pytest

from calib.dataset import SampleError, make_samples
from calib.identify import METHODS, IdentifyOptions, identify, split_rows
from calib.models import builtin_model
from calib.synthetic import make_true_cell, noisy_lengths, random_poses_deg

NOISE_MM = 0.05
MODEL = builtin_model("hsr-jr680")


def _cell_data(n_train: int = 100, n_test: int = 200, seed: int = 11, noise: float = NOISE_MM):
    cell = make_true_cell(MODEL)
    rng = np.random.default_rng(seed)
    q = random_poses_deg(cell, n_train + n_test, rng)
    clean = cell.lengths_mm(q)
    noisy = clean + rng.normal(0, noise, clean.shape)
    train = np.arange(n_train)
    test = np.arange(n_train, n_train + n_test)
    return cell, q, clean, noisy, train, test


@pytest.fixture(scope="module")
def clean_case():
    return _cell_data()


def test_heldout_rmse_and_parameters_within_three_sigma(clean_case) -> None:
    cell, q, clean, noisy, train, test = clean_case
    samples = make_samples(q, noisy)
    res = identify(MODEL, samples, IdentifyOptions(), train_rows=train, test_rows=test)
    # Held-out error against the noisy measurements: noise-limited.
    assert res.metrics["after"]["test"]["rmse_mm"] <= 1.5 * NOISE_MM
    assert res.metrics["before"]["test"]["rmse_mm"] > 10 * NOISE_MM
    # Against the truth: the identified model predicts the true lengths far better than σ.
    pred = res.to_json()
    assert pred["identifiability"]["unidentifiable"]  # theta1, d1, joint 6 at least
    # The identifiable combinations equal the truth's: fit noise-free data on the same base set.
    exact = identify(
        MODEL,
        make_samples(q, clean),
        IdentifyOptions(method="lm"),
        train_rows=train,
        test_rows=test,
    )
    assert exact.free_names == res.free_names
    # Exact up to what the noise-level threshold fixed: a trace far below one noise σ.
    assert exact.metrics["after"]["train"]["rmse_mm"] < 0.05 * NOISE_MM
    rank_only = identify(
        MODEL,
        make_samples(q, clean),
        IdentifyOptions(method="lm", noise_rank=False),
        train_rows=train,
        test_rows=test,
    )
    assert rank_only.metrics["after"]["train"]["rmse_mm"] < 1e-6
    idx = [res.layout.index(n) for n in res.free_names]
    z = (res.theta[idx] - exact.theta[idx]) / res.sigma[idx]
    worst = res.free_names[int(np.argmax(np.abs(z)))]
    assert np.all(np.abs(z) < 3.0), f"{worst}: {np.max(np.abs(z)):.2f} sigma"
    # DH parameters that are identifiable on their own come back close to the truth.
    for name in ("a2", "a3", "alpha2", "theta3"):
        i = res.layout.index(name)
        assert abs(res.theta[i] - cell.theta[i]) < 4 * res.sigma[i] + 1e-9, name


@pytest.mark.parametrize("method", METHODS)
def test_every_solver_converges_on_the_clean_case(clean_case, method: str) -> None:
    _, q, _, noisy, train, test = clean_case
    opts = IdentifyOptions(method=method, de_max_generations=60)  # type: ignore[arg-type]
    res = identify(MODEL, make_samples(q, noisy), opts, train_rows=train, test_rows=test)
    assert res.solver.status >= 0, res.solver.message
    limit = 3.0 if method == "de" else 1.5
    assert res.metrics["after"]["test"]["rmse_mm"] <= limit * NOISE_MM, method
    assert np.all(np.isfinite(res.theta))


def test_robust_mode_flags_gross_outliers_and_stays_close_to_clean(clean_case) -> None:
    _, q, _, noisy, train, test = clean_case
    rng = np.random.default_rng(5)
    corrupted = noisy.copy()
    bad = rng.choice(train, size=5, replace=False)  # 5 % of 100 training samples
    corrupted[bad] += rng.choice([-1, 1], 5) * rng.uniform(5, 20, 5)
    plain_opts = IdentifyOptions(method="lm", robust="none")
    clean_res = identify(
        MODEL, make_samples(q, noisy), plain_opts, train_rows=train, test_rows=test
    )
    plain = identify(
        MODEL, make_samples(q, corrupted), plain_opts, train_rows=train, test_rows=test
    )
    for mode in ("huber", "reject", "auto"):
        opts = IdentifyOptions(robust=mode)  # type: ignore[arg-type]
        res = identify(MODEL, make_samples(q, corrupted), opts, train_rows=train, test_rows=test)
        assert set(res.flagged_rows) >= set(bad.tolist()), mode
        assert len(res.flagged_rows) <= 8, mode
        got = res.metrics["after"]["test"]["rmse_mm"]
        assert got <= 1.3 * clean_res.metrics["after"]["test"]["rmse_mm"], (mode, got)
    # Without the robust mode the outliers bend the model: the test is meaningful.
    assert (
        plain.metrics["after"]["test"]["rmse_mm"]
        > 2 * clean_res.metrics["after"]["test"]["rmse_mm"]
    )


def test_two_anchors_each_get_their_own_p0_and_offset() -> None:
    cell = make_true_cell(MODEL, anchor_ids=("A", "B"), offsets_mm=np.array([-350.0, -120.0]))
    rng = np.random.default_rng(3)
    qa = random_poses_deg(cell, 60, rng, anchor_index=0)
    qb = random_poses_deg(cell, 60, rng, anchor_index=1)
    q = np.vstack([qa, qb])
    idx = np.r_[np.zeros(60, int), np.ones(60, int)]
    lengths = noisy_lengths(cell, q, rng, noise_mm=0.02, anchor_index=idx)
    samples = make_samples(q, lengths, anchor=["A"] * 60 + ["B"] * 60)
    res = identify(MODEL, samples, IdentifyOptions(method="lm", test_fraction=0.0))
    data = res.to_json()
    assert set(data["anchors"]) == {"B"}
    assert res.metrics["after"]["train"]["rmse_mm"] < 0.03
    assert "offset@B" in data["uncertainty"]


def test_grouped_holdout_keeps_whole_groups_out() -> None:
    cell = make_true_cell(MODEL)
    rng = np.random.default_rng(8)
    centres = random_poses_deg(cell, 6, rng)
    q = np.vstack([random_poses_deg(cell, 20, rng, spread_deg=3.0, centre_deg=c) for c in centres])
    groups = [f"g{i // 20}" for i in range(120)]
    samples = make_samples(q, cell.lengths_mm(q), group=groups)
    train, test = split_rows(samples, 0.3, 0, "grouped")
    test_groups = {groups[i] for i in test}
    train_groups = {groups[i] for i in train}
    assert test_groups and not (test_groups & train_groups)
    # Without a group column the clusters of joint angles recover the groups.
    no_groups = make_samples(q, cell.lengths_mm(q))
    train2, test2 = split_rows(no_groups, 0.3, 0, "grouped", n_groups=6)
    assert {groups[i] for i in test2}.isdisjoint({groups[i] for i in train2})


def test_prior_is_reported_and_keeps_local_data_physical() -> None:
    """A very local campaign (±4 deg per joint): ML over-fits, the MAP prior stays physical."""
    cell = make_true_cell(MODEL)
    rng = np.random.default_rng(21)
    centre = random_poses_deg(cell, 1, rng)[0]
    q = random_poses_deg(cell, 100, rng, spread_deg=4.0, centre_deg=centre)
    samples = make_samples(q, noisy_lengths(cell, q, rng, noise_mm=0.05))
    res = identify(MODEL, samples, IdentifyOptions(method="lm", prior=True, test_fraction=0.0))
    data = res.to_json()
    assert data["prior"]["used"] is True
    errs = np.array([[r["a_mm"], r["d_mm"]] for r in data["dh_error"]])
    assert np.all(np.abs(errs) < 10.0)
    assert data["metrics"]["after"]["train"]["rmse_mm"] < 0.2


def test_too_few_rows_is_a_clear_error() -> None:
    cell = make_true_cell(MODEL)
    q = random_poses_deg(cell, 12, np.random.default_rng(1))
    with pytest.raises(SampleError, match="training samples for"):
        identify(MODEL, make_samples(q, cell.lengths_mm(q)), IdentifyOptions(test_fraction=0.0))


def test_joint_angle_outside_limits_names_row_and_column() -> None:
    cell = make_true_cell(MODEL)
    q = random_poses_deg(cell, 40, np.random.default_rng(1))
    q[7, 4] = 170.0  # joint 5 limit is ±125
    with pytest.raises(SampleError, match=r"row 9, column 'q5'"):
        identify(MODEL, make_samples(q, cell.lengths_mm(q)))


def test_unknown_parameter_name_in_fix_is_rejected() -> None:
    cell = make_true_cell(MODEL)
    q = random_poses_deg(cell, 40, np.random.default_rng(1))
    with pytest.raises(ValueError, match="unknown parameter"):
        identify(MODEL, make_samples(q, cell.lengths_mm(q)), IdentifyOptions(fix=("a7",)))


def test_fixing_a_parameter_by_name_keeps_it_at_nominal(clean_case) -> None:
    _, q, _, noisy, train, test = clean_case
    res = identify(
        MODEL,
        make_samples(q, noisy),
        IdentifyOptions(method="lm", fix=("a2",)),
        train_rows=train,
        test_rows=test,
    )
    assert "a2" not in res.free_names
    assert res.theta[res.layout.index("a2")] == 0.0


def test_base_set_is_deterministic_for_exactly_redundant_parameters() -> None:
    """Regression: with the hook point on the flange axis (the start before the tool is fitted)
    two of the four joint-5 parameters are exactly redundant, and which two pivoted QR dropped
    (alpha5/theta5, a5/d5, d5/theta5) depended on the data set's rounding noise. Ties now go
    to the earlier parameter, whatever the poses, their order or duplication."""
    from calib.cable import ParamLayout, length_jacobian
    from calib.identifiability import analyse

    cell = make_true_cell(MODEL)
    layout = ParamLayout(("A",))
    theta = cell.theta.copy()
    theta[:27] = 0.0  # nominal DH table, hook point at the flange centre
    candidates = np.ones(layout.size, dtype=bool)
    sets = []
    for seed in range(6):
        rng = np.random.default_rng(seed)
        q = np.deg2rad(random_poses_deg(cell, 60, rng))
        _, jac = length_jacobian(MODEL, theta, q, np.zeros(60, dtype=int))
        first = analyse(jac, layout.names, candidates)
        sets.append(tuple(first.unidentifiable))
        for variant in (jac[rng.permutation(60)], np.vstack([jac, jac]), 3.0 * jac):
            assert analyse(variant, layout.names, candidates).base == first.base
    assert len(set(sets)) == 1, sets
    assert {"d3", "d5", "theta5"} <= set(sets[0])


def test_noise_threshold_drops_a_near_redundant_column_only_when_noise_hides_it() -> None:
    from calib.cable import N_DH, ParamLayout
    from calib.identifiability import analyse

    layout = ParamLayout(("A",))
    rng = np.random.default_rng(0)
    jac = rng.normal(size=(40, layout.size))
    d5 = layout.index("d5")
    # d5 = a5 plus 1e-3 of an independent direction: rank-full, but barely.
    jac[:, d5] = jac[:, layout.index("a5")] + 1e-3 * rng.normal(size=40)
    cand = np.ones(layout.size, bool)
    plausible = np.full(layout.size, np.inf)
    plausible[:N_DH] = 2.0
    loose = analyse(jac, layout.names, cand, noise_mm=1e-4, plausible=plausible)
    assert "d5" in loose.base and "a5" in loose.base
    # σ(d5) ≈ noise / (1e-3 · √40) ≈ 16 mm at 0.1 mm noise: above 2 mm, so one of the pair goes.
    tight = analyse(jac, layout.names, cand, noise_mm=0.1, plausible=plausible)
    dropped = {"a5", "d5"} - set(tight.base)
    assert len(dropped) == 1
    assert "below the noise" in tight.reasons[dropped.pop()]
    assert analyse(jac, layout.names, cand).base == loose.base  # no noise: rtol only


def test_noise_rank_fixes_joint5_terms_the_noise_cannot_resolve() -> None:
    """Hook near the flange axis: d5/theta5 are nearly redundant with the tool point. With
    ``noise_rank`` identify leaves out what 40 poses at 0.05 mm cannot resolve. (Off by
    default: the default MAP prior holds such parameters softly, to the same TCP accuracy.)"""
    cell = make_true_cell(MODEL)
    rng = np.random.default_rng(1)
    q = random_poses_deg(cell, 40, rng)
    samples = make_samples(q, noisy_lengths(cell, q, rng, noise_mm=0.05))
    on = identify(MODEL, samples, IdentifyOptions(method="lm", test_fraction=0.0, noise_rank=True))
    off = identify(MODEL, samples, IdentifyOptions(method="lm", test_fraction=0.0))
    joint5 = {"alpha5", "d5", "theta5"}
    assert joint5 <= set(off.identifiability.base)
    left_out = joint5 - set(on.identifiability.base)
    assert left_out
    assert all("below the noise" in on.identifiability.reasons[n] for n in left_out)


def test_elapsed_is_by_the_injected_clock_and_calib_reads_none(clean_case, monkeypatch) -> None:
    """calib reads no clock (issue 26): identify times itself and its fit only by the clock
    its caller passes; without one the run is not timed."""
    import time

    _, q, _, noisy, train, test = clean_case
    samples = make_samples(q, noisy)
    opts = IdentifyOptions(robust="none", prior_weight="fixed")

    def no_clock() -> float:
        raise AssertionError("calib read the clock")

    for name in ("perf_counter", "monotonic", "time", "process_time"):
        monkeypatch.setattr(time, name, no_clock)
    untimed = identify(MODEL, samples, opts, train_rows=train, test_rows=test)
    assert untimed.elapsed_s == 0.0 and untimed.solver.elapsed_s == 0.0
    ticks = iter(range(100))
    timed = identify(
        MODEL, samples, opts, train_rows=train, test_rows=test, clock=lambda: float(next(ticks))
    )
    # identify reads the clock at its start (0) and end (3); its one fit (robust none, a fixed
    # prior weight) between (1, 2).
    assert timed.solver.elapsed_s == 1.0
    assert timed.elapsed_s == 3.0
    assert np.array_equal(timed.theta, untimed.theta)
