"""The plan's noise from the cell (calib.planning.noise, daemon.api.plan_noise): each source and
their precedence."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from calib.planning import PlanOptions
from calib.planning.noise import (
    NoiseEstimate,
    choose,
    correlation_factor,
    repeat_noise_mm,
    still_windows,
    window_mean_se_mm,
)
from daemon.api.plan_noise import cell_noise
from daemon.sampler.config import SamplerConfig
from daemon.sampler.settle import PairedReading, make_capture
from daemon.store import Store

SIGMA_MM = 0.02  # per-reading noise of the made-up indicator [mm]
CFG = SamplerConfig(settle_s=0.3, settle_tol_mm=0.1)


def _held(rng: np.random.Generator, n: int, repeat: int) -> np.ndarray:
    """``n`` readings of an indicator that holds each noisy value for ``repeat`` polls [mm]."""
    values = rng.normal(0.0, SIGMA_MM, size=n // repeat + 1)
    return np.repeat(values, repeat)[:n]


@pytest.mark.parametrize("repeat", [1, 3])
def test_window_mean_se_matches_the_spread_of_window_means(repeat: int) -> None:
    """The SE from spread, count and correlation is the real spread of window means, for
    independent readings and for an indicator read 3 times per update (where s/√n alone
    would be √3 too small)."""
    rng = np.random.default_rng(repeat)
    windows = [_held(rng, 18, repeat) for _ in range(400)]
    truth = float(np.std([w.mean() for w in windows]))
    std = np.array([w.std(ddof=1) for w in windows])
    count = np.full(len(windows), 18.0)
    naive = window_mean_se_mm(std, count)
    se = window_mean_se_mm(std, count, windows)
    assert se == pytest.approx(truth, rel=0.2)
    if repeat == 1:
        assert correlation_factor(windows) == pytest.approx(1.0, abs=0.15)
    else:
        assert naive < 0.75 * truth  # the uncorrected figure is too low


def test_repeat_noise_pools_the_spread_at_the_same_pose_and_anchor() -> None:
    q = np.zeros((6, 6))
    q[3:, 0] = 10.0  # two poses, three samples each
    q[5, 1] = 0.001  # within the match tolerance
    lengths = np.array([100.0, 100.02, 99.98, 200.0, 200.01, 199.99])
    noise, dof = repeat_noise_mm(q, ["A"] * 6, lengths)
    assert dof == 4
    assert noise == pytest.approx(np.sqrt((0.0008 + 0.0002) / 4))
    # Another anchor is another sensor position: no repeat there.
    assert repeat_noise_mm(q, ["A", "B", "C", "D", "E", "F"], lengths)[1] == 0


def test_still_windows_leave_out_motion_and_over_range() -> None:
    t = np.arange(65) * 0.02  # 1.3 s of readings at 50 Hz: four windows of 0.3 s, and 5 more
    q = np.zeros((65, 6))
    q[15:30, 2] = np.linspace(0.0, 5.0, 15)  # the robot moves in the second window
    lengths = 500.0 + np.random.default_rng(0).normal(0.0, SIGMA_MM, 65)
    over = np.zeros(65, bool)
    over[50] = True  # and the indicator is over range in the fourth
    windows = still_windows(t, q, lengths, over, 0.3, 0.01, 0.1, 5)
    assert len(windows) == 2  # the first and third; the last 5 readings still fill one
    assert all(len(w) == 15 for w in windows)


def test_choose_takes_the_first_usable_source() -> None:
    samples = NoiseEstimate(0.006, "samples", "s")
    live = NoiseEstimate(0.005, "sampler", "l")
    assert choose(0.007, samples, live, 0.05).source == "result"
    assert choose(None, samples, live, 0.05) == samples
    assert choose(float("nan"), None, live, 0.05) == live
    assert choose(0.0, NoiseEstimate(0.0, "samples", "s"), None, 0.05).source == "default"
    assert choose(None, None, None, 0.05) == NoiseEstimate(
        0.05, "default", choose(None, None, None, 0.05).detail
    )


class _Sampler:
    """A sampler whose ring buffer is ``readings`` (what cell_noise reads of it)."""

    def __init__(self, readings: list[PairedReading]) -> None:
        self.readings = readings

    def recent_readings(self, since_wall_s: float, limit: int) -> list[PairedReading]:
        return self.readings[-limit:]


def _readings(
    rng: np.random.Generator, q: tuple[float, ...], t0: float, n: int, repeat: int = 2
) -> list[PairedReading]:
    """``n`` still readings at 100 Hz of an indicator updating at 100/repeat Hz."""
    lengths = 800.0 + _held(rng, n, repeat)
    joints = (q[0], q[1], q[2], q[3], q[4], q[5])
    return [
        PairedReading(
            t0 + i * 0.01, t0 + i * 0.01, 1e9 + t0 + i * 0.01, joints, float(lengths[i]), False, 0.0
        )
        for i in range(n)
    ]


def test_cell_noise_sources_in_order(tmp_path: Path) -> None:
    """default → live sampler → the campaign's captures → repeat poses → accepted result;
    each later one, once there, wins over the earlier ones."""
    rng = np.random.default_rng(5)
    store = Store(tmp_path / "cablecal.db")
    robot_id = int(store.ensure_builtin_robot("hsr-jr680")["id"])
    cid = int(store.create_campaign("c", robot_id)["id"])

    est = cell_noise(store, None, CFG, cid, robot_id)
    assert (est.source, est.noise_mm) == ("default", PlanOptions().noise_mm)

    live = _Sampler(_readings(rng, (0.0,) * 6, 0.0, 600))  # 6 s still: 20 windows of 30
    est = cell_noise(store, live, CFG, cid, robot_id)
    assert est.source == "sampler"
    # Held twice: a window mean of 30 readings has 15 independent ones.
    assert est.noise_mm == pytest.approx(SIGMA_MM / np.sqrt(15), rel=0.35)

    for k in range(4):  # four captures at four poses
        window = _readings(rng, (float(k),) + (0.0,) * 5, 10.0 * k, 30)
        store.store_capture(cid, make_capture(window, "A", "auto"))
    est = cell_noise(store, live, CFG, cid, robot_id)
    assert est.source == "samples" and "lower bound" in est.detail
    assert est.noise_mm == pytest.approx(SIGMA_MM / np.sqrt(15), rel=0.5)

    for k in range(4):  # each pose again, with a 0.05 mm repeatability on top
        window = _readings(rng, (float(k),) + (0.0,) * 5, 100.0 + 10.0 * k, 30)
        shifted = [
            PairedReading(
                r.t_poll,
                r.t_mono,
                r.t_wall,
                r.joints_deg,
                r.length_mm + 0.05 * (-1) ** k,
                False,
                0.0,
            )
            for r in window
        ]
        store.store_capture(cid, make_capture(shifted, "A", "auto"))
    est = cell_noise(store, live, CFG, cid, robot_id)
    assert est.source == "samples" and "repeated poses" in est.detail
    assert est.noise_mm > 0.02  # the repeatability shows; the readings' spread alone hid it

    job = store.create_job(cid, robot_id, "geolm", {})
    store.save_result(int(job["id"]), {"prior": {"noise_mm": 0.0123}}, accepted=False)
    assert cell_noise(store, live, CFG, cid, robot_id).source == "samples"  # not accepted
    job = store.create_job(cid, robot_id, "geolm", {})  # given its noise, measured none
    store.save_result(int(job["id"]), {"prior": {"noise_mm": 0.05, "weight": "fixed"}})
    assert cell_noise(store, live, CFG, cid, robot_id).source == "samples"
    job = store.create_job(cid, robot_id, "geolm", {})
    store.save_result(int(job["id"]), {"prior": {"noise_mm": 0.0123}}, accepted=True)
    est = cell_noise(store, live, CFG, cid, robot_id)
    assert (est.source, est.noise_mm) == ("result", 0.0123)


def test_the_plan_route_records_the_noise_and_its_source(tmp_path: Path) -> None:
    """A given noise_mm wins (source ``request``); without one, the cell's (here the default:
    a fake sampler with no buffer, no samples, no result)."""
    from fastapi.testclient import TestClient
    from test_service import AUTH, TOKEN, FakeSampler, _settings

    from daemon.api.main import create_app

    app = create_app(_settings(tmp_path), TOKEN, sampler_factory=FakeSampler)
    body = {"anchors_mm": [[1430.0, 330.0, 230.0]], "n": 8, "candidates": 200, "seed": 2}
    with TestClient(app) as c:
        r = c.post(
            "/api/v1/campaigns", json={"name": "p", "robot_model": "hsr-jr680"}, headers=AUTH
        )
        cid = r.json()["id"]
        r = c.post(f"/api/v1/campaigns/{cid}/plan", json=body, headers=AUTH)
        assert r.status_code == 201, r.text
        s = r.json()["summary"]
        assert (s["noise_mm"], s["noise_source"]) == (PlanOptions().noise_mm, "default")
        rms = s["tcp_sigma_mm"]["plan"]["rms"]
        r = c.post(f"/api/v1/campaigns/{cid}/plan", json={**body, "noise_mm": 0.005}, headers=AUTH)
        s = r.json()["summary"]
        assert (s["noise_mm"], s["noise_source"]) == (0.005, "request")
        assert s["tcp_sigma_mm"]["plan"]["rms"] == pytest.approx(rms * 0.005 / 0.05, rel=1e-6)
        r = c.post(f"/api/v1/campaigns/{cid}/plan", json={**body, "noise_mm": None}, headers=AUTH)
        assert r.json()["summary"]["noise_source"] == "default"
