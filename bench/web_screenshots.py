"""The README's screenshots of the operator page (``make screenshots``): docs/img/web-*.png.

Runs a campaign on a fresh EMULATED cell through the REST API (plan, auto capture, identify,
accept, compensate, a hold check), then opens the page in headless chromium at 1366 px width
and saves one full-page screenshot per view.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

from calib.default_robot import DEFAULT_ROBOT_MODEL
from daemon.cli.emulated import FAST_DAEMON_ENV, Cell, fast_cell_toml, wait_for

ROOT = Path(__file__).resolve().parents[1]
IMG = ROOT / "docs" / "img"
N_SAMPLES = 45
TOKEN = "screenshots-token-0123"
ANCHOR_MM = (1400.0, 300.0, 200.0)  # the emulated cell's sensor (simulator default)


def main() -> None:
    sys.path.insert(0, str(ROOT / "tests"))
    from browser import offline_page

    IMG.mkdir(parents=True, exist_ok=True)
    with (
        tempfile.TemporaryDirectory(prefix="cablecal-shots-") as tmp,
        Cell(Path(tmp), fast_cell_toml(300, 7, 0.35, 0.9), TOKEN, FAST_DAEMON_ENV) as cell,
    ):
        assert cell.daemon is not None
        api = cell.daemon.client(timeout_s=300)
        c = api.post(
            "/campaigns", json={"name": "cell 4 – JR680 #2", "robot_model": DEFAULT_ROBOT_MODEL}
        )
        cid = c.json()["id"]
        api.post(f"/campaigns/{cid}/plan", json={"n": 40, "anchors_mm": [list(ANCHOR_MM)]})
        api.put(f"/campaigns/{cid}/auto-capture", json={"enabled": True})
        wait_for(
            lambda: len(api.get(f"/campaigns/{cid}/samples").json()) >= N_SAMPLES,
            N_SAMPLES * 6.0,
            1.0,
            "captures",
        )
        api.put(f"/campaigns/{cid}/auto-capture", json={"enabled": False})
        samples = api.get(f"/campaigns/{cid}/samples").json()
        api.patch(f"/samples/{samples[3]['id']}", json={"excluded": True, "reason": "bumped"})
        job = api.post(f"/campaigns/{cid}/identifications", json={"method": "ukf-vslm"}).json()
        wait_for(
            lambda: api.get(f"/identifications/{job['id']}").json()["status"] == "succeeded",
            300,
            1.0,
            "identification",
        )
        api.post(f"/identifications/{job['id']}/accept")
        targets = "q1,q2,q3,q4,q5,q6\n" + "\n".join(
            ",".join(f"{s[f'q{j}']:.2f}" for j in range(1, 7)) for s in samples[:8]
        )
        url = cell.daemon.url
        with offline_page((1366, 768), allowed_origin=url) as (page, log):
            page.goto(f"{url}/#token={TOKEN}")
            page.wait_for_function("window.__cablecal.trace.updates > 40", timeout=30000)
            page.screenshot(path=str(IMG / "web-cell.png"), full_page=True)
            for view, ready in (
                ("campaign", "#samples tbody tr"),
                ("identify", "#chart-residuals canvas"),
            ):
                page.click(f"#tabs button[data-view={view}]")
                page.wait_for_selector(ready, timeout=30000)
                time.sleep(2.0)
                page.screenshot(path=str(IMG / f"web-{view}.png"), full_page=True)
            page.click("#tabs button[data-view=apply]")
            page.fill("#compensate-form textarea", targets)
            page.click("#compensate-form button[type=submit]")
            page.wait_for_selector("#compensate-result tbody tr", timeout=60000)
            time.sleep(3.5)
            page.screenshot(path=str(IMG / "web-apply.png"), full_page=True)
            problems = log.console_errors + log.page_errors + log.blocked_requests
    print(f"wrote {IMG}/web-{{cell,campaign,identify,apply}}.png; problems: {problems or 'none'}")


if __name__ == "__main__":
    main()
