"""The live sensor watch end to end with real processes: ``cablecal simulate`` + ``cablecal
serve``. The first 30 poses are imported (the EMULATED cell's true lengths plus seeded noise,
so the test does not wait for 30 captures); then the daemon's auto capture takes the cell's
readings over the pty and TCP while the cell visits 30 new poses. After a few captures the
sensor stand is bumped (control command ``move_anchor``, 4 mm along x): a ``sensor_moved``
event must follow within 15 samples, the samples from the bump on go to a new anchor, auto
capture goes on with it, the operator page (Playwright on Debian's chromium, when installed)
shows a banner, and its undo button puts the samples back."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from browser import CHROMIUM_PATH, offline_page

from daemon.cli.emulated import FAST_CELL_NOISE_MM, FAST_DAEMON_ENV, Cell, fast_cell_toml, wait_for

pytestmark = [pytest.mark.slow, pytest.mark.timeout(150)]

N_IMPORTED = 30


def _samples(api: httpx.Client, cid: int) -> list[dict[str, Any]]:
    r = api.get(f"/campaigns/{cid}/samples")
    r.raise_for_status()
    return list(r.json())


def test_a_bumped_sensor_is_found_within_15_samples_and_can_be_undone(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    t0 = time.monotonic()
    toml = fast_cell_toml(n_poses=2 * N_IMPORTED, seed=7, move_s=0.3, dwell_s=0.7)
    with Cell(tmp_path, toml, daemon_env=FAST_DAEMON_ENV) as cell:
        assert cell.daemon is not None and cell.sim is not None
        api, sim = cell.daemon.client(), cell.sim
        q = np.array(sim.control("poses")["poses_deg"])
        truth = np.array(sim.control("true_lengths", joints_deg=q.tolist())["lengths_mm"])
        noisy = truth + np.random.default_rng(3).normal(0.0, FAST_CELL_NOISE_MM, truth.shape)
        r = api.post("/campaigns", json={"name": "watch", "robot_model": "hsr-jr680"})
        cid = int(r.json()["id"])
        rows = ["q1,q2,q3,q4,q5,q6,L"] + [
            ",".join(f"{v:.6f}" for v in (*q[i], noisy[i])) for i in range(N_IMPORTED)
        ]
        r = api.post(
            f"/campaigns/{cid}/samples/import",
            content="\n".join(rows) + "\n",
            headers={"Content-Type": "text/csv"},
        )
        assert r.status_code in (200, 201), r.text
        sim.control("load_poses", poses_deg=q[N_IMPORTED:].tolist(), loop=False)
        assert api.put(f"/campaigns/{cid}/auto-capture", json={"enabled": True}).status_code == 200
        wait_for(lambda: len(_samples(api, cid)) >= N_IMPORTED + 4, 60, 0.2, "4 auto captures")
        n_before = len(_samples(api, cid))
        sim.control("move_anchor", delta_mm=[4, 0, 0])

        events = wait_for(
            lambda: api.get("/events", params={"kind": "sensor_moved"}).json(),
            40,
            0.3,
            "a sensor_moved event",
        )
        detail = events[0]["detail"]
        samples = _samples(api, cid)
        ids = [s["id"] for s in samples]
        detected_at = ids.index(detail["detected_at_sample_id"]) + 1  # 1-based count
        assert detected_at - n_before <= 15, (n_before, detail)
        # The move is placed at the bump: no sample captured before it is moved (the one
        # being captured while the stand moved may go either way).
        first = ids.index(detail["sample_id"]) + 1
        assert n_before <= first <= n_before + 2, (n_before, detail)
        assert detail["previous_anchor"] == "A" and detail["new_anchor"] == "A2"
        assert detail["step_mm"] > 2.0  # 4 mm along x lengthens the cable at these poses
        assert detail["fit"] == "identify"
        anchors = {s["id"]: s["anchor"] for s in samples}
        assert {anchors[i] for i in detail["moved_sample_ids"]} == {"A2"}
        assert all(anchors[i] == "A" for i in ids[: first - 1])
        status = api.get("/status").json()
        assert status["sampler"]["auto_anchor"] == "A2"
        assert [m["campaign_id"] for m in status["watch"]["moves"]] == [cid]
        metrics = httpx.get(cell.daemon.url + "/metrics").text
        assert 'cablecal_sensor_moved_total{robot="' in metrics

        if CHROMIUM_PATH.exists():
            _undo_on_the_page(cell, cid, detail)
        else:  # no browser: the same route the page's button calls
            r = api.post(f"/campaigns/{cid}/sensor-moved/undo")
            assert r.status_code == 200, r.text
            assert r.json()["anchor"] == "A" and r.json()["from_anchor"] == "A2"
        assert {s["anchor"] for s in _samples(api, cid)} == {"A"}
        assert api.get("/status").json()["sampler"]["auto_anchor"] == "A"
        assert api.get("/status").json()["watch"]["moves"] == []
        assert api.post(f"/campaigns/{cid}/sensor-moved/undo").status_code == 409
        with capsys.disabled():
            print(
                f"\nwatch e2e: bump after sample {n_before}, detected at sample "
                f"{detected_at} ({detected_at - n_before} later), step "
                f"{detail['step_mm']:+.2f} mm; {time.monotonic() - t0:.0f} s"
            )


def _undo_on_the_page(cell: Cell, cid: int, detail: dict[str, Any]) -> None:
    """The banner names the campaign, the sample and the size; its button undoes the split."""
    assert cell.daemon is not None
    url = cell.daemon.url
    with offline_page(allowed_origin=url) as (page, log):
        page.goto(f"{url}/#token={cell.daemon.token}")
        banner = page.locator("#watch-banner")
        banner.wait_for(timeout=15000)
        text = banner.inner_text()
        assert f"Campaign #{cid}: from sample #{detail['sample_id']}" in text, text
        assert f"{detail['step_mm']:+.2f} mm" in text and "anchor session A2" in text, text
        page.get_by_role("button", name="Undo: back to anchor A").click()
        banner.wait_for(state="detached", timeout=10000)
        page.wait_for_selector("text=are back in anchor A", timeout=5000)
        assert log.page_errors == [] and log.console_errors == [], log
        assert log.blocked_requests == []


N_PROGRAM = 42  # poses of the program; its first run is imported
N_SECOND = 24  # poses of its second run, captured by auto capture
MOVE_AFTER = 6  # captures of the second run before the sensor moves


def _identify(api: httpx.Client, cid: int) -> dict[str, Any]:
    r = api.post(f"/campaigns/{cid}/identifications", json={})
    assert r.status_code == 202, r.text
    job_id = r.json()["id"]
    job: dict[str, Any] = wait_for(
        lambda: (
            (j := api.get(f"/identifications/{job_id}").json())["status"]
            in ("succeeded", "failed", "cancelled")
            and j
        ),
        90,
        0.5,
        "the identification job",
    )
    assert job["status"] == "succeeded", job
    result: dict[str, Any] = job["result"]
    return result


def test_a_move_during_a_second_run_of_the_program_moves_every_later_sample(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Issue 27 item 1: the sensor moved 3 mm during a second run of the same program (the
    same poses again), square to the cable at the next poses; every sample captured after
    the move lands in the new anchor session (the one being captured while the stand moved
    may go either way), none before it, and the campaign's default identify is within 1.5×
    of the same campaign without the move and at most 0.05 mm held-out."""
    from calib.dataset import make_samples
    from calib.identify import identify
    from calib.models import builtin_model

    toml = fast_cell_toml(n_poses=N_PROGRAM, seed=9, move_s=0.3, dwell_s=0.7)
    # Auto capture takes no pose twice by default (auto_new_pose_deg): 0 lets the second run
    # of the program be captured, as manual captures would.
    env = {**FAST_DAEMON_ENV, "CABLECAL_SAMPLER__AUTO_NEW_POSE_DEG": "0"}
    with Cell(tmp_path, toml, daemon_env=env) as cell:
        assert cell.daemon is not None and cell.sim is not None
        api, sim = cell.daemon.client(), cell.sim
        q = np.array(sim.control("poses")["poses_deg"])[:N_PROGRAM]
        truth = np.array(sim.control("true_lengths", joints_deg=q.tolist())["lengths_mm"])
        rng = np.random.default_rng(4)
        first_run = truth + rng.normal(0.0, FAST_CELL_NOISE_MM, truth.shape)
        cid = int(
            api.post("/campaigns", json={"name": "rerun", "robot_model": "hsr-jr680"}).json()["id"]
        )
        rows = ["q1,q2,q3,q4,q5,q6,L"] + [
            ",".join(f"{v:.6f}" for v in (*q[i], first_run[i])) for i in range(N_PROGRAM)
        ]
        r = api.post(
            f"/campaigns/{cid}/samples/import",
            content="\n".join(rows) + "\n",
            headers={"Content-Type": "text/csv"},
        )
        assert r.status_code in (200, 201), r.text
        # The move: 3 mm square to the cable at the next two poses, plus what changes their
        # lengths by 0.3 mm: inside the watch's band (0.5 mm), so its run starts late, but
        # 15 times the noise (the case of the issue). The length's gradient by the sensor
        # position there, from the cell's truth.
        nxt = q[MOVE_AFTER : MOVE_AFTER + 2].tolist()
        base = np.array(sim.control("true_lengths", joints_deg=nxt)["lengths_mm"])
        grad = []
        for axis in np.eye(3):
            sim.control("move_anchor", delta_mm=axis.tolist())
            grad.append(np.array(sim.control("true_lengths", joints_deg=nxt)["lengths_mm"]) - base)
            sim.control("move_anchor", delta_mm=(-axis).tolist())
        g = np.array(grad).T  # (2, 3): d length / d P0 at those poses
        square = np.cross(g[0], g[1])
        move = 3.0 * square / np.linalg.norm(square) + np.linalg.pinv(g) @ np.full(2, 0.3)
        sim.control("load_poses", poses_deg=q[:N_SECOND].tolist(), loop=False)
        assert api.put(f"/campaigns/{cid}/auto-capture", json={"enabled": True}).status_code == 200
        wait_for(
            lambda: len(_samples(api, cid)) >= N_PROGRAM + MOVE_AFTER,
            60,
            0.1,
            "the second run's first captures",
        )
        moved_at = time.time()
        sim.control("move_anchor", delta_mm=move.tolist())
        wait_for(
            lambda: len(_samples(api, cid)) >= N_PROGRAM + N_SECOND,
            90,
            0.3,
            "the second run's captures",
        )
        api.put(f"/campaigns/{cid}/auto-capture", json={"enabled": False})
        events = wait_for(
            lambda: api.get("/events", params={"kind": "sensor_moved"}).json(),
            20,
            0.3,
            "a sensor_moved event",
        )
        detail = events[0]["detail"]
        time.sleep(2.0)  # the watch tests the last captures
        samples = _samples(api, cid)
        captured = [s for s in samples if s["source"] == "capture"]
        after = [s for s in captured if s["t_start"] > moved_at]
        before = [s for s in captured if s["t_end"] < moved_at]
        in_flight = [s for s in captured if s not in after and s not in before]
        assert len(in_flight) <= 1, in_flight
        assert [s["id"] for s in after if s["anchor"] != "A2"] == [], detail
        assert [s["id"] for s in before if s["anchor"] != "A"] == [], detail
        # the event names the samples it moved (later captures went to A2 directly)
        in_a2 = {s["id"] for s in samples if s["anchor"] == "A2"}
        assert set(detail["moved_sample_ids"]) <= in_a2, detail
        assert min(in_a2) == detail["sample_id"], detail

        result = _identify(api, cid)
        held_out = result["metrics"]["after"]["test"]["rmse_mm"]
        # The same campaign with the sensor held still: the second run at the lengths of the
        # sensor before the move (the cell's truth with the move undone), the same noise.
        second = np.array([[s[f"q{j}"] for j in range(1, 7)] for s in captured])
        sim.control("move_anchor", delta_mm=(-move).tolist())
        still = np.array(sim.control("true_lengths", joints_deg=second.tolist())["lengths_mm"])
        still += rng.normal(0.0, FAST_CELL_NOISE_MM, len(second))
        clean_samples = make_samples(np.vstack([q, second]), np.concatenate([first_run, still]))
        clean = identify(builtin_model("hsr-jr680"), clean_samples)
        clean_held_out = clean.to_json()["metrics"]["after"]["test"]["rmse_mm"]
        assert held_out <= 0.05 and held_out <= 1.5 * clean_held_out, (held_out, clean_held_out)
        with capsys.disabled():
            print(
                f"\nwatch e2e, second run: move after capture {N_PROGRAM + MOVE_AFTER}, "
                f"split at sample {detail['sample_id']}; {len(after)} later captures all in "
                f"A2, {len(in_flight)} in flight; held-out {held_out:.4f} mm (still: "
                f"{clean_held_out:.4f} mm)"
            )
