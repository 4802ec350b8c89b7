"""End to end, the plan reaches the robot: plan → robot program → the EMULATED robot runs it →
auto capture → every plan pose captured → identify, with real processes on loopback
(``cablecal simulate`` + ``cablecal serve``), driven over HTTP as the page would.

The identification's predicted tool-point σ must come within 1.5x of what the plan promised
(both ways), the plan taking its noise from the cell (no ``noise_mm`` in the request),
and the result must say it followed the plan. Short moves and dwells keep it to about half a
minute; the emulated robot takes its timing from its config, not from the program.

The program is fetched as an operator does, with the page's download button in a real browser
(Playwright on Debian's chromium; where it is missing, the same REST download is used and the
page part is skipped with a note): the buttons are the REST enum's formats, and the file
saved is the one the daemon serves, named for the controller.
"""

from __future__ import annotations

import re
import time
from pathlib import Path

import pytest
from browser import CHROMIUM_PATH, offline_page

from calib.programs import DOWNLOAD_FORMATS
from calib.programs.registry import parse_program
from daemon.cli.emulated import (
    FAST_CELL_NOISE_MM,
    FAST_DAEMON_ENV,
    Cell,
    fast_cell_toml,
    wait_for,
)

pytestmark = [pytest.mark.slow, pytest.mark.timeout(300)]

N_POSES = 40
TOKEN = "e2e-program-token-0123"
#: The emulated cell's true anchor (simulator.config.CellSection's default) [mm].
ANCHOR_MM = [1400.0, 300.0, 200.0]


def _page_download(url: str, fmt: str, out: Path) -> Path | None:
    """The plan downloaded with the page's button for ``fmt`` (the campaign view opens on the
    newest campaign), or None without a browser."""
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        return None
    if not CHROMIUM_PATH.exists():
        return None
    with offline_page((1366, 768), allowed_origin=url) as (page, log):
        page.goto(f"{url}/#token={TOKEN}")
        page.click("#tabs button[data-view=campaign]")
        page.wait_for_selector(f"#plan-downloads:not([hidden]) button[data-format={fmt}]")
        labels = page.eval_on_selector_all(
            "#plan-downloads button", "bs => bs.map(b => b.id || b.textContent)"
        )
        assert labels == list(DOWNLOAD_FORMATS)  # the REST enum, in its order
        with page.expect_download() as info:
            page.click(f"#plan-downloads button[data-format={fmt}]")
        out.mkdir(parents=True, exist_ok=True)
        path = out / info.value.suggested_filename
        info.value.save_as(path)
        assert log.console_errors == [] and log.page_errors == []
    return path


def test_the_robot_runs_the_plan_and_the_result_keeps_its_promise(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    toml = fast_cell_toml(n_poses=4, seed=11, move_s=0.25, dwell_s=0.7)
    with Cell(tmp_path, toml, TOKEN, daemon_env=FAST_DAEMON_ENV) as cell:
        assert cell.daemon is not None and cell.sim is not None
        api = cell.daemon.client()
        r = api.post("/campaigns", json={"name": "plan-e2e", "robot_model": "hsr-jr680"})
        cid = int(r.json()["id"])
        # No noise_mm: the daemon takes it from the cell (here, a new robot and campaign:
        # the live indicator's still windows, as a capture averages them). A cell PC has
        # watched its indicator long before anyone plans; this one just started.
        wait_for(
            lambda: api.get("/status").json()["sampler"]["readings_in_buffer"] >= 250,
            30,
            0.2,
            "the sampler's first readings",
        )
        # Four more dwells (0.95 s a pose): a capture window of 0.3 s lies wholly inside a
        # dwell only at some phases of the grid, and on a loaded machine some windows fall
        # short of min_readings; the estimate needs 3 still windows.
        time.sleep(4.0)
        body = {
            "anchors_mm": [ANCHOR_MM],
            "n": N_POSES,
            "candidates": 1500,
            "seed": 1,
            "extension_mm": [400.0, 1900.0],
        }
        r = api.post(f"/campaigns/{cid}/plan", json=body, timeout=120)
        assert r.status_code == 201, r.text
        summary = r.json()["summary"]
        planned_rms = summary["tcp_sigma_mm"]["plan"]["rms"]
        assert summary["noise_source"] == "sampler", summary
        # A window mean is far quieter than one reading (FAST_CELL_NOISE_MM).
        assert 0 < summary["noise_mm"] < FAST_CELL_NOISE_MM / 2
        # The plan as a KUKA program, as the page's download gives it; the robot runs it.
        r = api.get(f"/campaigns/{cid}/plan", params={"format": "krl"})
        assert r.status_code == 200, r.text
        name = re.search(r'filename="([^"]+)"', r.headers["content-disposition"])
        assert name is not None and name.group(1) == f"campaign_{cid}_plan.src"
        program = _page_download(cell.daemon.url, "krl", tmp_path / "page")
        if program is None:
            program = tmp_path / name.group(1)
            program.write_text(r.text, encoding="utf-8")
        assert program.name == name.group(1)  # KSS finds the DEF by the file name
        served = parse_program("krl", r.text).joints_deg
        assert parse_program("krl", program.read_text(encoding="utf-8")).joints_deg == served
        reply = cell.sim.control("load_poses", program=str(program), loop=False)
        assert len(reply["poses_deg"]) == N_POSES
        api.put(f"/campaigns/{cid}/auto-capture", json={"enabled": True})
        progress = wait_for(
            lambda: (
                (p := api.get(f"/campaigns/{cid}/plan").json()["progress"])["n_done"] == N_POSES
                and p
            ),
            120,
            0.5,
            f"all {N_POSES} plan poses captured",
        )
        api.put(f"/campaigns/{cid}/auto-capture", json={"enabled": False})
        assert progress["n_pending"] == 0 and progress["next_pose"] is None
        r = api.post(
            f"/campaigns/{cid}/identifications",
            json={"method": "geolm", "test_fraction": 0.0, "seed": 0},
        )
        assert r.status_code == 202, r.text
        job_id = r.json()["id"]
        job = wait_for(
            lambda: (
                (j := api.get(f"/identifications/{job_id}").json())["status"]
                in ("succeeded", "failed", "cancelled")
                and j
            ),
            120,
            0.5,
            "the identification job",
        )
        assert job["status"] == "succeeded", job
    result = job["result"]
    achieved_rms = result["tcp_uncertainty_mm"]["rms"]
    check = result["plan_check"]
    with capsys.disabled():
        print(
            f"\ne2e plan→program→robot: {check['n_measured']}/{N_POSES} plan poses captured "
            f"({check['n_samples']} samples); TCP σ RMS achieved {achieved_rms:.4f} mm, "
            f"planned {planned_rms:.4f} mm (x{achieved_rms / planned_rms:.2f}, limit x1.5); "
            f"noise planned {check['plan_noise_mm']:.4f} mm ({summary['noise_source']}), "
            f"fit {check['fit_noise_mm']:.4f} mm; {summary['noise_detail']}; "
            f"at the fit's noise x{check['sigma_ratio_at_fit_noise']:.2f}"
        )
    assert check["on_plan"] and check["n_measured"] == N_POSES and check["n_off_plan"] == 0
    assert check["sigma_ratio"] == pytest.approx(achieved_rms / planned_rms)
    assert check["plan_noise_source"] == "sampler"
    # The plan's promise holds both ways: neither too rosy nor too gloomy.
    assert 1 / 1.5 <= achieved_rms / planned_rms <= 1.5
    # At the noise the fit found, the plan's design alone predicts the result.
    assert 1 / 1.5 <= check["sigma_ratio_at_fit_noise"] <= 1.5
