"""End to end with real processes on loopback: ``cablecal simulate`` + ``cablecal serve``.

The emulated cell holds the truth (Table XII D1 errors on hsr-jr680, a true P0 and zero offset,
seeded noise); the daemon reads it over a pseudo-terminal (Modbus RTU, 115200 baud) and the
Huashu SocketCmd TCP server, exactly as on a real cell. The tests drive everything over HTTP.
"""

from __future__ import annotations

import sqlite3
import time
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from prometheus_client.parser import text_string_to_metric_families

from calib.predict import predict_lengths_from_result
from daemon.cli.emulated import (
    FAST_CELL_NOISE_MM,
    FAST_DAEMON_ENV,
    Cell,
    fast_cell_toml,
    wait_for,
)

pytestmark = [pytest.mark.slow, pytest.mark.timeout(420)]

NOISE_MM = FAST_CELL_NOISE_MM
DAEMON_ENV = FAST_DAEMON_ENV


def sim_toml(n_poses: int, seed: int = 3, move_s: float = 0.35, dwell_s: float = 0.9) -> str:
    """A fast emulated cell: 115200 baud, short moves and dwells, free TCP ports."""
    return fast_cell_toml(n_poses, seed, move_s, dwell_s)


def _samples(api: httpx.Client, cid: int) -> list[dict[str, Any]]:
    r = api.get(f"/campaigns/{cid}/samples")
    r.raise_for_status()
    return list(r.json())


def _metrics(url: str) -> dict[tuple[str, tuple[tuple[str, str], ...]], float]:
    """Every sample of ``/metrics``, parsed with prometheus-client's parser."""
    text = httpx.get(url + "/metrics").text
    return {
        (s.name, tuple(sorted(s.labels.items()))): s.value
        for family in text_string_to_metric_families(text)
        for s in family.samples
    }


def _new_campaign(api: httpx.Client, name: str) -> int:
    r = api.post("/campaigns", json={"name": name, "robot_model": "hsr-jr680"})
    assert r.status_code == 201, r.text
    return int(r.json()["id"])


def _joints(samples: list[dict[str, Any]]) -> np.ndarray:
    return np.array([[s[f"q{j}"] for j in range(1, 7)] for s in samples])


def test_campaign_end_to_end_recovers_the_cells_truth(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with Cell(tmp_path, sim_toml(n_poses=90), daemon_env=DAEMON_ENV) as cell:
        assert cell.daemon is not None and cell.sim is not None
        api = cell.daemon.client()
        assert api.get("/health").json()["status"] == "ok"
        cid = _new_campaign(api, "e2e")
        metrics_before = _metrics(cell.daemon.url)
        r = api.put(f"/campaigns/{cid}/auto-capture", json={"enabled": True})
        assert r.status_code == 200, r.text
        wait_for(lambda: len(_samples(api, cid)) >= 64, 240, 1.0, "64 auto captures")
        api.put(f"/campaigns/{cid}/auto-capture", json={"enabled": False})
        samples = _samples(api, cid)
        q = _joints(samples)
        # The Prometheus counters moved with the campaign.
        metrics_after = _metrics(cell.daemon.url)
        key = (
            "cablecal_captures_total",
            (("mode", "auto"), ("outcome", "accepted"), ("reason", "ok")),
        )
        assert metrics_after[key] - metrics_before.get(key, 0.0) >= len(samples)
        polls = ("cablecal_device_polls_total", (("device", "indicator"), ("role", "indicator")))
        assert metrics_after[polls] > metrics_before[polls] + 10 * len(samples)
        # Each pose once: no two captures at the same pose.
        d = np.abs(q[:, None, :] - q[None, :, :]).max(axis=2) + np.eye(len(q)) * 1e9
        assert d.min() > 0.05
        # Every stored length matches the truth at its joints (mean of the settled window).
        truth = np.array(cell.sim.control("true_lengths", joints_deg=q.tolist())["lengths_mm"])
        lengths = np.array([s["length_mm"] for s in samples])
        assert np.abs(lengths - truth).max() < 4 * NOISE_MM + 0.01

        r = api.post(
            f"/campaigns/{cid}/identifications",
            json={"method": "ukf-vslm", "test_fraction": 0.2, "seed": 0},
        )
        assert r.status_code == 202, r.text
        job_id = r.json()["id"]
        job = wait_for(
            lambda: (
                (j := api.get(f"/identifications/{job_id}").json())["status"]
                in ("succeeded", "failed", "cancelled")
                and j
            ),
            180,
            0.5,
            "the identification job",
        )
        assert job["status"] == "succeeded", job
        result = job["result"]
        # Held-out accuracy against the cell's truth, at poses never captured.
        poses = np.array(cell.sim.control("poses")["poses_deg"])
        seen = np.abs(poses[:, None, :] - q[None, :, :]).max(axis=2).min(axis=1) < 0.05
        held_out = poses[~seen]
        assert len(held_out) >= 10, len(held_out)
        true_held = np.array(
            cell.sim.control("true_lengths", joints_deg=held_out.tolist())["lengths_mm"]
        )
        pred = predict_lengths_from_result(result, held_out)
        rmse = float(np.sqrt(np.mean((pred - true_held) ** 2)))
        with capsys.disabled():
            print(
                f"\ne2e: {len(samples)} auto captures; held-out RMSE vs the cell's truth "
                f"{rmse:.4f} mm over {len(held_out)} new poses (limit {2 * NOISE_MM} mm)"
            )
        assert rmse <= 2 * NOISE_MM, rmse
        assert result["metrics"]["after"]["test"]["rmse_mm"] < 2 * NOISE_MM
        assert result["metrics"]["before"]["test"]["rmse_mm"] > 10 * NOISE_MM
        robot_id = api.get(f"/campaigns/{cid}").json()["robot_id"]
        model = api.get(f"/robots/{robot_id}/calibrated-model")
        # Emulated truth is physically plausible, so the result is accepted automatically.
        assert result["plausibility"]["plausible"], result["plausibility"]
        assert model.status_code == 200 and model.json()["job_id"] == job_id


def test_sigkill_during_auto_capture_loses_no_acknowledged_sample(tmp_path: Path) -> None:
    with Cell(
        tmp_path, sim_toml(n_poses=60, move_s=0.3, dwell_s=0.7), daemon_env=DAEMON_ENV
    ) as cell:
        assert cell.daemon is not None
        api = cell.daemon.client()
        cid = _new_campaign(api, "crash")
        api.put(f"/campaigns/{cid}/auto-capture", json={"enabled": True})
        wait_for(lambda: len(_samples(api, cid)) >= 6, 120, 0.5, "6 captures")
        acknowledged = {s["id"]: s for s in _samples(api, cid)}
        cell.daemon.kill()
        db = tmp_path / "cablecal.sqlite3"
        con = sqlite3.connect(db)
        assert con.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
        con.close()
        # Restart on the same state: nothing acknowledged is lost, and sampling resumes.
        cell.start_daemon()
        api = cell.daemon.client()
        after = {s["id"]: s for s in _samples(api, cid)}
        for sid, sample in acknowledged.items():
            assert sid in after, f"sample {sid} lost"
            assert after[sid]["length_mm"] == sample["length_mm"]
        n0 = len(after)
        wait_for(lambda: len(_samples(api, cid)) >= n0 + 3, 90, 0.5, "capture after restart")
        assert api.get(f"/campaigns/{cid}").json()["auto_capture"] is True
        q = _joints(_samples(api, cid))
        d = np.abs(q[:, None, :] - q[None, :, :]).max(axis=2) + np.eye(len(q)) * 1e9
        assert d.min() > 0.05, "a pose was captured twice across the restart"


def test_crc_errors_and_a_link_drop_store_no_corrupt_sample(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    with Cell(
        tmp_path, sim_toml(n_poses=60, move_s=0.3, dwell_s=0.8), daemon_env=DAEMON_ENV
    ) as cell:
        assert cell.daemon is not None and cell.sim is not None
        api = cell.daemon.client()
        cid = _new_campaign(api, "faults")
        cell.sim.control("fault", indicator_crc_error_rate=0.05)
        api.put(f"/campaigns/{cid}/auto-capture", json={"enabled": True})
        wait_for(lambda: len(_samples(api, cid)) >= 4, 120, 0.5, "captures under CRC errors")
        cell.sim.control("link_down", target="indicator", duration_s=3.0)
        t_drop_end = time.time() + 3.0
        wait_for(
            lambda: api.get("/events", params={"kind": "link_down"}).json(),
            30,
            0.5,
            "a link_down event",
        )
        wait_for(
            lambda: (
                [s for s in _samples(api, cid) if s["t_start"] > t_drop_end][:3] != []
                and len([s for s in _samples(api, cid) if s["t_start"] > t_drop_end]) >= 3
            ),
            120,
            0.5,
            "captures after the link came back",
        )
        api.put(f"/campaigns/{cid}/auto-capture", json={"enabled": False})
        samples = _samples(api, cid)
        q = _joints(samples)
        truth = np.array(cell.sim.control("true_lengths", joints_deg=q.tolist())["lengths_mm"])
        lengths = np.array([s["length_mm"] for s in samples])
        worst = float(np.abs(lengths - truth).max())
        with capsys.disabled():
            print(
                f"\ne2e faults: {len(samples)} samples under 5 % CRC errors and a 3 s drop; "
                f"worst |error| {worst:.4f} mm"
            )
        assert worst < 4 * NOISE_MM + 0.01
        events = api.get("/events", params={"limit": 1000}).json()
        kinds = {e["kind"] for e in events}
        assert "link_down" in kinds and "link_up" in kinds, kinds
        metrics = httpx.get(cell.daemon.url + "/metrics").text
        assert 'error="IndicatorCRCError"' in metrics or "IndicatorCRCError" in metrics
