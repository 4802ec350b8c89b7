"""Issue 27 item 2 with real processes: the EMULATED cell (``cablecal simulate``, its
indicator zeroed 350 mm out: a cable shorter than that reads below 0, over range) and
``cablecal serve``. A plan made before any sample cannot know the zero offset, so some of its
poses read below 0; the robot runs the plan, the sampler refuses those poses (over range), and
the plan's progress marks them "not capturable" apart from the pending ones, on the API and
on the operator page (Playwright on Debian's chromium, when installed). A plan on top of the
samples knows the offset and keeps every predicted reading in range."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from browser import CHROMIUM_PATH, offline_page

from daemon.cli.emulated import FAST_DAEMON_ENV, Cell, fast_cell_toml, wait_for

pytestmark = [pytest.mark.slow, pytest.mark.timeout(240)]

#: The emulated cell's zero offset [mm] (simulator.config.CellSection's default).
OFFSET_MM = -350.0
ANCHOR = [1400.0, 300.0, 200.0]


def test_poses_over_the_range_are_not_capturable_and_the_next_plan_avoids_them(
    tmp_path: Path,
) -> None:
    toml = fast_cell_toml(n_poses=4, seed=3, move_s=0.3, dwell_s=1.2)
    with Cell(tmp_path, toml, daemon_env=FAST_DAEMON_ENV) as cell:
        assert cell.daemon is not None and cell.sim is not None
        api, sim = cell.daemon.client(), cell.sim
        assert sim.control("truth")["offset_mm"] == OFFSET_MM
        cid = int(
            api.post("/campaigns", json={"name": "range", "robot_model": "hsr-jr680"}).json()["id"]
        )
        body = {"anchors_mm": [ANCHOR], "n": 24, "candidates": 1500, "seed": 5}
        r = api.post(f"/campaigns/{cid}/plan", json=body)
        assert r.status_code == 201, r.text
        made = r.json()
        assert made["summary"]["reading_mm"] is None  # no offset known yet
        # the poses whose cable is shorter than the zero: they read below 0
        short = [p["pose"] for p in made["poses"] if p["extension_mm"] + OFFSET_MM < -5.0]
        fine = [p["pose"] for p in made["poses"] if p["extension_mm"] + OFFSET_MM > 5.0]
        assert short, [p["extension_mm"] for p in made["poses"]]  # the test can fail
        q = [[p[f"q{j}"] for j in range(1, 7)] for p in made["poses"]]
        sim.control("load_poses", poses_deg=q, loop=False)
        assert api.put(f"/campaigns/{cid}/auto-capture", json={"enabled": True}).status_code == 200

        def progress() -> dict[str, Any]:
            got: dict[str, Any] = api.get(f"/campaigns/{cid}/plan").json()
            return got

        wait_for(
            lambda: (
                (pr := progress()["progress"])["n_done"] + pr["n_not_capturable"]
                >= len(fine) + len(short)
            ),
            120,
            0.5,
            "every planned pose visited",
        )
        api.put(f"/campaigns/{cid}/auto-capture", json={"enabled": False})
        got = progress()
        status = {p["pose"]: p for p in got["poses"]}
        for k in short:
            assert status[k]["status"] == "not_capturable", status[k]
            assert status[k]["why"].startswith("over_range"), status[k]
        assert all(status[k]["status"] == "done" for k in fine), got["progress"]
        pr = got["progress"]
        assert pr["n_not_capturable"] == len(short) and pr["next_pose"] not in short

        if CHROMIUM_PATH.exists():
            url = cell.daemon.url
            with offline_page(allowed_origin=url) as (page, log):
                page.goto(f"{url}/#token={cell.daemon.token}")
                page.click("#tabs button[data-view=campaign]")
                page.wait_for_function(
                    "document.getElementById('plan-summary').textContent.includes("
                    "'not capturable')",
                    timeout=15000,
                )
                summary = page.inner_text("#plan-summary")
                assert f"{len(short)} not capturable" in summary, summary
                rows = page.locator("#plan-poses tbody tr")
                cells = rows.nth(short[0] - 1).inner_text()
                assert "not capturable: over range: the indicator" in cells, cells
                assert log.page_errors == [] and log.console_errors == [], log

        # planned again on top of the samples: the offset is known, every reading in range
        again = {"n": 8, "candidates": 1500, "seed": 5, "start_from_samples": True}
        r = api.post(f"/campaigns/{cid}/plan", json=again)
        assert r.status_code == 201, r.text
        reading = r.json()["summary"]["reading_mm"]
        assert reading["offsets_mm"]["A"] == pytest.approx(OFFSET_MM, abs=20.0), reading
        lo, hi = reading["window_mm"]
        assert lo <= reading["min"] and reading["max"] <= hi, reading
        for p in r.json()["poses"]:
            assert p["extension_mm"] + OFFSET_MM > 0.0, p
