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
        r = api.post(f"/campaigns/{cid}/samples/import", content="\n".join(rows) + "\n",
                     headers={"Content-Type": "text/csv"})  # fmt: skip
        assert r.status_code in (200, 201), r.text
        sim.control("load_poses", poses_deg=q[N_IMPORTED:].tolist(), loop=False)
        assert api.put(f"/campaigns/{cid}/auto-capture", json={"enabled": True}).status_code == 200
        wait_for(lambda: len(_samples(api, cid)) >= N_IMPORTED + 4, 60, 0.2, "4 auto captures")
        n_before = len(_samples(api, cid))
        sim.control("move_anchor", delta_mm=[4, 0, 0])

        events = wait_for(
            lambda: api.get("/events", params={"kind": "sensor_moved"}).json(),
            40, 0.3, "a sensor_moved event",
        )  # fmt: skip
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
            print(f"\nwatch e2e: bump after sample {n_before}, detected at sample "
                  f"{detected_at} ({detected_at - n_before} later), step "
                  f"{detail['step_mm']:+.2f} mm; {time.monotonic() - t0:.0f} s")  # fmt: skip


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
