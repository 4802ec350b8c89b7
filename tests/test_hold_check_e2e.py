"""Hold checks end to end with real processes: ``cablecal simulate`` + ``cablecal serve``.

The calibration campaign is imported (the EMULATED cell's true lengths at its 60 poses plus
seeded noise, so the test does not wait for 60 captures); the checks are real: the daemon's
auto capture takes the cell's indicator and controller readings over the pty and TCP while
the cell follows the check poses (control command ``load_poses``). Five checks of the
unchanged cell raise no alarm; after ``shift_joint_offset`` (joint 2 by 0.05 deg in the cell's
TRUE model) the next check is ``not_held``.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest

from daemon.cli.emulated import FAST_CELL_NOISE_MM, FAST_DAEMON_ENV, Cell, fast_cell_toml, wait_for

# About 75 s alone on 2 shared cores; the timeout bounds it under contention.
pytestmark = [pytest.mark.slow, pytest.mark.timeout(180)]

DAEMON_ENV = {**FAST_DAEMON_ENV, "CABLECAL_HOLD_CHECK__TIMEOUT_S": "60"}


def _csv(q: np.ndarray, lengths: np.ndarray) -> str:
    lines = ["q1,q2,q3,q4,q5,q6,L"]
    lines += [
        ",".join(f"{v:.6f}" for v in (*row, length)) for row, length in zip(q, lengths, strict=True)
    ]
    return "\n".join(lines) + "\n"


def _calibrate(api: httpx.Client, sim: Any) -> tuple[int, float]:
    """Import the cell's truth at its poses (+ noise), identify, accept; robot id and the
    identification's test RMSE [mm]."""
    q = np.array(sim.control("poses")["poses_deg"])
    truth = np.array(sim.control("true_lengths", joints_deg=q.tolist())["lengths_mm"])
    lengths = truth + np.random.default_rng(5).normal(0.0, FAST_CELL_NOISE_MM, truth.shape)
    r = api.post("/campaigns", json={"name": "calibration", "robot_model": "hsr-jr680"})
    cid = int(r.json()["id"])
    r = api.post(
        f"/campaigns/{cid}/samples/import",
        content=_csv(q, lengths),
        headers={"Content-Type": "text/csv"},
    )
    assert r.status_code in (200, 201), r.text
    r = api.post(
        f"/campaigns/{cid}/identifications",
        json={"method": "ukf-vslm", "test_fraction": 0.2, "seed": 0},
    )
    job_id = r.json()["id"]
    job = wait_for(
        lambda: (
            (j := api.get(f"/identifications/{job_id}").json())["status"] in ("succeeded", "failed")
            and j
        ),
        90,
        0.5,
        "the identification",
    )
    assert job["status"] == "succeeded", job
    if not job["accepted"]:
        assert api.post(f"/identifications/{job_id}/accept").status_code == 200
    robot_id = int(api.get(f"/campaigns/{cid}").json()["robot_id"])
    return robot_id, float(job["result"]["metrics"]["after"]["test"]["rmse_mm"])


def _check(api: httpx.Client, sim: Any, robot_id: int, poses: list[list[float]]) -> dict[str, Any]:
    """One check: the cell follows the check poses, the daemon captures and judges."""
    sim.control("load_poses", poses_deg=poses, loop=True)
    r = api.post(f"/robots/{robot_id}/checks")
    assert r.status_code == 202, r.text
    check_id = r.json()["id"]

    def done() -> dict[str, Any] | None:
        rows = api.get(f"/robots/{robot_id}/checks").json()
        row = next(c for c in rows if c["id"] == check_id)
        return None if row["status"] == "running" else dict(row)

    return dict(wait_for(done, 70, 0.5, f"check {check_id}"))


def test_a_changed_robot_is_flagged_and_an_unchanged_cell_is_not(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    t0 = time.monotonic()
    toml = fast_cell_toml(n_poses=60, seed=4, move_s=0.3, dwell_s=0.7)
    with Cell(tmp_path, toml, daemon_env=DAEMON_ENV) as cell:
        assert cell.daemon is not None and cell.sim is not None
        api = cell.daemon.client()
        robot_id, calib_rmse = _calibrate(api, cell.sim)
        poses = api.get(f"/robots/{robot_id}/check-poses").json()
        assert poses["source"] == "default" and len(poses["poses_deg"]) == 8
        quiet = [_check(api, cell.sim, robot_id, poses["poses_deg"]) for _ in range(5)]
        assert [c["status"] for c in quiet] == ["ok"] * 5, quiet
        assert api.get("/events", params={"kind": "hold_check_not_held"}).json() == []
        reply = cell.sim.control("shift_joint_offset", joint=2, delta_deg=0.05)
        assert reply["joint"] == 2
        changed = _check(api, cell.sim, robot_id, poses["poses_deg"])
        assert changed["status"] == "not_held", changed
        status = api.get("/status").json()["hold_check"]
        assert status["state"] == "not_held" and status["check_id"] == changed["id"]
        assert status["rms_mm"] == pytest.approx(changed["rms_mm"])
        metrics = httpx.get(cell.daemon.url + "/metrics").text
        assert f'cablecal_hold_check_rms_mm{{robot="{robot_id}"}} {changed["rms_mm"]}' in metrics
        assert api.get("/events", params={"kind": "hold_check_not_held"}).json()
        with capsys.disabled():
            print(
                f"\nhold check e2e: calibration test RMSE {calib_rmse:.4f} mm, threshold "
                f"{quiet[0]['threshold_mm']:.4f} mm; unchanged cell RMS "
                f"{[round(c['rms_mm'], 4) for c in quiet]} mm; joint 2 +0.05 deg: RMS "
                f"{changed['rms_mm']:.4f} mm; {time.monotonic() - t0:.0f} s"
            )
