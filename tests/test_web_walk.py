"""Issue 27, the operator's second walk, page side: each defect the page had, walked in
chromium (Playwright on Debian's /usr/bin/chromium) against the real processes (the EMULATED
cell and ``cablecal serve``): the state before, the operator's action, the state after.

- the plan form's pose count (minimum and recommended, from the API) and its own error;
- errors as sentences with the API's text behind "details", cleared when the action succeeds;
- model downloads for the accepted calibration only; the comparison table reads the tiles'
  figures; the drift wording of a method without drift is the result's, on the page and in
  the report;
- the sensor-moved banner: an Undo button, the anchor column, the session in use, what next;
- narrow screens (390×844, 800×1280): no sideways scroll, the tabs fit; ARIA tabs; axe-core
  (from the ``axe-playwright-python`` package, nothing fetched) finds no critical or serious
  violation on any view.

The samples an identification needs are imported (the bundled real data), not captured, to
keep the run short; only the sensor-moved walk captures (a handful of poses).
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from browser import offline_page, require_chromium

from calib.dataset import make_samples, samples_to_csv
from daemon.cli.emulated import FAST_CELL_NOISE_MM, FAST_DAEMON_ENV, Cell, fast_cell_toml, wait_for
from daemon.datafiles import read_samples

pytestmark = [pytest.mark.slow, pytest.mark.timeout(300)]

TOKEN = "web-walk-token-0123"
PHONE = (390, 844)
TABLET = (800, 1280)
VIEWS = ("cell", "campaign", "identify", "apply")
N_IMPORTED = 30  # the watch's first fit (the sensor-moved walk)


@pytest.fixture(scope="module")
def cell(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Cell]:
    require_chromium()
    pytest.importorskip("axe_playwright_python", reason="the walk checks axe-core")
    work = tmp_path_factory.mktemp("web-walk")
    toml = fast_cell_toml(n_poses=2 * N_IMPORTED, seed=7, move_s=0.3, dwell_s=0.7)
    with Cell(work, toml, TOKEN, FAST_DAEMON_ENV) as c:
        yield c


def _import(api: httpx.Client, cid: int, rows: np.ndarray) -> None:
    data = read_samples(None).subset(rows)
    csv = samples_to_csv(make_samples(data.joints_deg, data.length_mm))
    r = api.post(
        f"/campaigns/{cid}/samples/import", content=csv, headers={"Content-Type": "text/csv"}
    )
    assert r.is_success, r.text


@pytest.fixture(scope="module")
def result_walk(cell: Cell) -> int:
    """The id of the "result walk" campaign: 60 imported rows identified by lm and that result
    accepted, so its robot is calibrated. A fixture, not a side effect of one test, so each
    test that needs it runs alone or on any xdist worker."""
    assert cell.daemon is not None
    api = cell.daemon.client()
    cid = int(
        api.post("/campaigns", json={"name": "result walk", "robot_model": "hsr-jr680"}).json()[
            "id"
        ]
    )
    _import(api, cid, np.arange(60))
    first = api.post(f"/campaigns/{cid}/identifications", json={"method": "lm"}).json()["id"]
    wait_for(
        lambda: api.get(f"/identifications/{first}").json()["status"] == "succeeded",
        120,
        0.5,
        "the lm identification",
    )
    if not api.get(f"/identifications/{first}").json()["current"]:
        assert api.post(f"/identifications/{first}/accept").is_success
    return cid


def _open(page: Any, url: str, view: str) -> None:
    page.goto(f"{url}/#token={TOKEN}")
    page.wait_for_function("window.__cablecal && window.__cablecal.trace.updates > 0")
    page.click(f"#tabs button[data-view={view}]")


def _axe_serious(page: Any) -> list[str]:
    """axe-core's critical and serious violations of the page as it is: ``id (n nodes)``."""
    from axe_playwright_python.sync_playwright import Axe

    found = Axe().run(page).response["violations"]
    return [
        f"{v['id']} ({len(v['nodes'])}): {v['nodes'][0]['target']}"
        for v in found
        if v["impact"] in ("critical", "serious")
    ]


def _fits(page: Any) -> None:
    """No sideways scroll of the page itself; the four tabs inside the viewport."""
    width, client = page.evaluate(
        "[document.documentElement.scrollWidth, document.documentElement.clientWidth]"
    )
    assert width <= client, f"the page scrolls sideways: {width} > {client} px"
    for view in VIEWS:
        box = page.locator(f"#tab-{view}").bounding_box()
        assert box is not None and box["x"] >= 0 and box["x"] + box["width"] <= client, view


def test_plan_form_errors_and_small_screen(cell: Cell, tmp_path: Path) -> None:
    """Items 3, 4 (warnings, error sentences), 6, 7 at 390×844."""
    assert cell.daemon is not None
    url, api = cell.daemon.url, cell.daemon.client()
    cid = api.post("/campaigns", json={"name": "plan walk", "robot_model": "hsr-jr680"}).json()[
        "id"
    ]
    campaign = api.get(f"/campaigns/{cid}").json()
    need, recommended = campaign["min_samples_to_identify"], campaign["recommended_samples"]
    with offline_page(PHONE, allowed_origin=url) as (page, log):
        _open(page, url, "campaign")
        page.wait_for_function(
            f"document.getElementById('campaign-title').textContent.startsWith('Campaign #{cid}:')"
        )
        n = page.locator("#plan-form input[name=n]")
        # before: the count starts at the recommended one, the minimum is enforced, both said
        page.wait_for_function(
            f"document.querySelector('#plan-form input[name=n]').min === '{need}'"
        )
        assert n.input_value() == str(recommended)
        note = page.inner_text("#plan-count-note")
        assert f"At least {need} poses" in note and f"{recommended} recommended" in note, note
        # action: too few poses -> refused on the page in words, nothing sent
        n.fill("2")
        for axis, value in zip("xyz", (1400, 300, 200), strict=True):
            page.fill(f"#plan-form input[name=a{axis}]", str(value))
        page.click("#plan-form button[type=submit]")
        error = page.locator("#plan-form-error")
        error.wait_for()
        assert "2 is too few" in error.inner_text() and str(need) in error.inner_text()
        assert api.get(f"/campaigns/{cid}").json()["plan_id"] is None
        # the sensor position missing: the form's own error, not a banner on every tab
        n.fill(str(recommended))
        for axis in "xyz":
            page.fill(f"#plan-form input[name=a{axis}]", "")
        page.click("#plan-form button[type=submit]")
        page.wait_for_function(
            "document.getElementById('plan-form-error').textContent.includes('sensor position')"
        )
        assert page.locator("#messages .message").count() == 0
        page.screenshot(path=str(tmp_path / "plan-form-error.png"), full_page=True)
        # after: the position typed, the error goes by itself (its cause is gone)
        for axis, value in zip("xyz", (1400, 300, 200), strict=True):
            page.fill(f"#plan-form input[name=a{axis}]", str(value))
        page.wait_for_selector("#plan-form-error[hidden]", state="attached")

        # the daemon refuses a request: a sentence, the API's text behind "details"
        page.evaluate(
            """cid => import('/static/js/api.js').then(m => m.api('POST', `/campaigns/${cid}/plan`,
                 {json: {n: 40, anchors_mm: [[20000, 0, 0]]}})).catch(() => {})""",
            cid,
        )
        banner = page.locator("#messages .message.error")
        banner.wait_for()
        headline = banner.locator(".headline").inner_text()
        assert headline.startswith("The poses were not planned: "), headline
        assert "sensor position x must be at most 10000" in headline, headline
        assert "POST" not in headline and "422" not in headline and "anchors_mm" not in headline
        details = banner.locator("details")
        assert not details.locator("code").is_visible()
        details.locator("summary").click()
        assert "anchors_mm.0.0" in details.locator("code").inner_text()
        # a plan that succeeds clears the refusal of the same action
        page.click("#plan-form button[type=submit]")
        page.wait_for_function(
            f"document.querySelectorAll('#plan-poses tbody tr').length === {recommended}",
            timeout=120000,
        )
        banner.wait_for(state="detached", timeout=5000)
        assert page.locator("#plan-form-error").is_hidden()

        # narrow screen: every view fits, the tabs are ARIA tabs, axe finds nothing serious
        for view in VIEWS:
            page.click(f"#tab-{view}")
            page.wait_for_timeout(400)
            assert page.get_attribute(f"#tab-{view}", "aria-selected") == "true"
            others = [v for v in VIEWS if v != view]
            assert all(page.get_attribute(f"#tab-{v}", "aria-selected") == "false" for v in others)
            assert page.locator(f"#view-{view} h1").count() == 1
            _fits(page)
            assert _axe_serious(page) == [], view
            page.screenshot(path=str(tmp_path / f"phone-{view}.png"), full_page=True)
        assert page.get_attribute("#tabs", "role") == "tablist"
        # the cable chart's y-axis: no label twice, on a steady cable (a few hundredths of a
        # mm over the minute) as on a moving one
        labels = page.evaluate(
            "import('/static/js/charts.js')"
            ".then(m => m.linearTicks(null, [1034.02, 1034.03, 1034.04]))"
        )
        assert labels == ["1034.02", "1034.03", "1034.04"], labels
        page.click("#tab-cell")
        page.wait_for_function("window.__cablecal.trace.updates > 5")
        y_labels = page.evaluate("window.__cablecal.trace.plot.axes[1]._values")
        shown = [v for v in y_labels if v]
        assert len(shown) >= 2 and len(set(shown)) == len(shown), y_labels
        # the arrow keys move between the tabs
        page.focus("#tab-apply")
        page.keyboard.press("ArrowLeft")
        assert page.get_attribute("#tab-identify", "aria-selected") == "true"
        assert log.page_errors == [] and log.blocked_requests == []


def test_result_downloads_comparison_and_drift_wording(
    cell: Cell, result_walk: int, tmp_path: Path
) -> None:
    """Item 4: model downloads for the accepted result only; the comparison table reads the
    tiles' figures (and says when the samples changed since); the drift line of ukf-vslm is
    the result's, on the page and in the report. At 800×1280, axe on the result."""
    assert cell.daemon is not None
    url, api = cell.daemon.url, cell.daemon.client()
    cid = result_walk
    with offline_page(TABLET, allowed_origin=url) as (page, log):
        page.on("dialog", lambda d: d.accept())
        _open(page, url, "campaign")
        page.click("#campaign-list tr:has-text('result walk')")
        page.click("#tab-identify")
        page.wait_for_selector("#identify-start:not([disabled])", timeout=20000)
        page.select_option("#identify-form select[name=method]", "ukf-vslm")
        page.click("#identify-start")
        page.wait_for_selector("#compare:not([hidden])", timeout=120000)
        second = api.get(f"/campaigns/{cid}/identifications").json()[-1]
        assert second["method"] == "ukf-vslm" and not second["current"]
        result = api.get(f"/identifications/{second['id']}").json()["result"]

        # before Accept: no model download, and the page says why (no click-then-warn)
        for kind in ("toml", "urdf"):
            assert page.is_disabled(f"[data-download={kind}]")
        assert "accept this result first" in page.inner_text("#model-download-note")
        # the table's figures are the tiles' (one source: the result)
        tiles = page.inner_text("#result-tiles")
        own = f"{result['metrics']['after']['test']['rmse_mm']:.3f}"
        row = page.locator("#compare-table tbody tr").first.inner_text()
        assert own in tiles and row.split("\t")[-1].strip() == own, (row, tiles)
        assert page.is_hidden("#compare-stale")
        # one drift line: the result's, which says ukf-vslm did not look for drift
        summary = result["drift"]["summary"]
        assert page.inner_text("#result-drift") == summary and "not looked for" in summary
        with page.expect_download() as info:
            page.click("[data-download=report]")
        report = Path(info.value.path()).read_text(encoding="utf-8")
        assert summary in report and "held still" not in report
        assert _axe_serious(page) == []
        page.screenshot(path=str(tmp_path / "compare.png"), full_page=True)

        # the samples change after the identification (held-out rows excluded): the table
        # keeps the tiles' figure and says the result no longer matches the campaign
        test_ids = result["split"]["test_sample_ids"][:4]
        for sid in test_ids:
            r = api.patch(f"/samples/{sid}", json={"excluded": True, "reason": "walk"})
            assert r.is_success
        page.reload()
        page.click("#tab-identify")
        page.click("#job-list tr:has-text('ukf-vslm')")
        page.wait_for_selector("#compare-stale:not([hidden])", timeout=20000)
        row = page.locator("#compare-table tbody tr").first.inner_text()
        assert row.split("\t")[-1].strip() == own and own in page.inner_text("#result-tiles")
        assert "changed since" in page.inner_text("#compare-stale")

        # after Accept: the model downloads work, with no warning left behind
        page.click("#accept")
        page.wait_for_function(
            "document.getElementById('result-verdict').textContent.startsWith('current')",
            timeout=15000,
        )
        assert page.is_enabled("[data-download=toml]")
        assert page.inner_text("#model-download-note") == ""
        with page.expect_download() as info:
            page.click("[data-download=toml]")
        assert Path(info.value.path()).read_text(encoding="utf-8").strip()
        assert page.locator("#messages .message.warn, #messages .message.error").count() == 0
        assert log.page_errors == [] and log.blocked_requests == []


def test_sensor_moved_banner(cell: Cell, tmp_path: Path) -> None:
    """Item 5: the sensor is bumped while auto capture runs. Before: anchor A everywhere.
    After the watch's split: the banner says what next and how many samples Identify needs
    now (the API's count), the samples table shows A2 for the moved samples, the Capture card
    the session in use (A2); Undo is a real button and puts everything back to A."""
    assert cell.daemon is not None and cell.sim is not None
    url, api, sim = cell.daemon.url, cell.daemon.client(), cell.sim
    q = np.array(sim.control("poses")["poses_deg"])
    truth = np.array(sim.control("true_lengths", joints_deg=q.tolist())["lengths_mm"])
    noisy = truth + np.random.default_rng(3).normal(0.0, FAST_CELL_NOISE_MM, truth.shape)
    cid = api.post("/campaigns", json={"name": "bump walk", "robot_model": "hsr-jr680"}).json()[
        "id"
    ]
    rows = ["q1,q2,q3,q4,q5,q6,L"] + [
        ",".join(f"{v:.6f}" for v in (*q[i], noisy[i])) for i in range(N_IMPORTED)
    ]
    r = api.post(
        f"/campaigns/{cid}/samples/import",
        content="\n".join(rows) + "\n",
        headers={"Content-Type": "text/csv"},
    )
    assert r.is_success, r.text
    sim.control("load_poses", poses_deg=q[N_IMPORTED:].tolist(), loop=False)
    with offline_page(TABLET, allowed_origin=url) as (page, log):
        _open(page, url, "campaign")
        page.click("#campaign-list tr:has-text('bump walk')")
        page.wait_for_function(
            f"document.getElementById('campaign-title').textContent.startsWith('Campaign #{cid}:')"
        )
        # before: one session, A, in the table and on the Capture card
        headers = page.locator("#samples thead th").all_inner_texts()
        anchor_col = headers.index("anchor")
        assert "" not in [h.strip() for h in headers]  # no empty header (axe)
        assert page.input_value("#capture-anchor") == "A"
        page.check("#auto-capture")
        wait_for(
            lambda: len(api.get(f"/campaigns/{cid}/samples").json()) >= N_IMPORTED + 4,
            60,
            0.2,
            "4 auto captures",
        )
        sim.control("move_anchor", delta_mm=[4, 0, 0])
        banner = page.locator("#watch-banner")
        banner.wait_for(timeout=60000)
        page.screenshot(path=str(tmp_path / "banner-first.png"), full_page=True)
        move = api.get("/status").json()["watch"]["moves"][0]
        need = api.get(f"/campaigns/{cid}").json()["min_samples_to_identify"]
        page.wait_for_function(
            "document.getElementById('watch-banner')?.textContent"
            f".includes('needs {need} included')",
            timeout=15000,
        )
        text = banner.inner_text()
        assert "Next:" in text and "keep capturing" in text and "undo" in text, text
        undo = banner.get_by_role("button", name="Undo: back to anchor A")
        style = undo.evaluate("b => getComputedStyle(b).backgroundColor")
        assert style not in ("rgba(0, 0, 0, 0)", "transparent"), style  # looks like a button
        page.wait_for_function(
            "document.getElementById('capture-anchor').value === 'A2'", timeout=10000
        )
        assert "Anchor session in use: A2" in page.inner_text("#capture-state")
        page.wait_for_function(
            f"[...document.querySelectorAll('#samples tbody tr')].some("
            f"r => r.cells[{anchor_col}].textContent === 'A2')",
            timeout=10000,
        )
        page.screenshot(path=str(tmp_path / "banner.png"), full_page=True)
        assert _axe_serious(page) == []  # the campaign view with samples and the banner
        assert move["new_anchor"] == "A2"
        # action: Undo; after: one session again, everywhere
        undo.click()
        banner.wait_for(state="detached", timeout=10000)
        page.wait_for_function(
            f"[...document.querySelectorAll('#samples tbody tr')].every("
            f"r => r.cells[{anchor_col}].textContent === 'A')",
            timeout=10000,
        )
        page.wait_for_function(
            "document.getElementById('capture-anchor').value === 'A'", timeout=10000
        )
        page.uncheck("#auto-capture")
        assert log.page_errors == [] and log.blocked_requests == []
    deadline = time.monotonic() + 10
    while api.get("/status").json()["sampler"]["mode"] == "auto" and time.monotonic() < deadline:
        time.sleep(0.2)


def _still_joints(api: httpx.Client) -> list[float]:
    """The robot's joints once it has stood still for 2 s (the EMULATED cell has run through
    its poses and stays at the last one)."""
    last: list[float] = []
    since = time.monotonic()
    deadline = since + 90
    while time.monotonic() < deadline:
        q = api.get("/status").json()["devices"]["robot"]["last_reading"]["value"]
        if not last or max(abs(a - b) for a, b in zip(q, last, strict=True)) > 1e-6:
            last, since = q, time.monotonic()
        elif time.monotonic() - since > 2.0:
            return last
        time.sleep(0.2)
    raise AssertionError("the robot did not stand still")


def test_a_repeat_manual_capture_asks_first(cell: Cell) -> None:
    """Item 8: Capture now at a pose the campaign has already: the page asks; "no" stores
    nothing and says why, "yes" stores it (the same rule as auto capture)."""
    assert cell.daemon is not None
    url, api = cell.daemon.url, cell.daemon.client()
    cid = api.post("/campaigns", json={"name": "repeat walk", "robot_model": "hsr-jr680"}).json()[
        "id"
    ]
    _still_joints(api)
    count = lambda: len(api.get(f"/campaigns/{cid}/samples").json())  # noqa: E731
    dialogs: list[str] = []
    with offline_page(TABLET, allowed_origin=url) as (page, log):
        _open(page, url, "campaign")
        page.click("#campaign-list tr:has-text('repeat walk')")
        page.wait_for_function(
            f"document.getElementById('campaign-title').textContent.startsWith('Campaign #{cid}:')"
        )
        # before: a new pose is stored without a question
        answer = {"yes": False}

        def on_dialog(d: Any) -> None:
            dialogs.append(d.message)
            d.accept() if answer["yes"] else d.dismiss()

        page.on("dialog", on_dialog)
        page.click("#capture-now")
        wait_for(lambda: count() == 1, 30, 0.2, "the first capture")
        first_id = api.get(f"/campaigns/{cid}/samples").json()[0]["id"]
        page.wait_for_selector(f"#messages .message:has-text('Sample #{first_id} ')")
        assert dialogs == []
        # action: Capture now again at the same pose -> asked; "no": nothing stored, words
        page.wait_for_selector("#capture-now:not([disabled])")
        page.click("#capture-now")
        page.wait_for_selector("#messages .message:has-text('Not captured')", timeout=30000)
        assert len(dialogs) == 1 and "captured already" in dialogs[0], dialogs
        assert "not_new_pose" not in dialogs[0]
        assert count() == 1
        # "yes": stored as a second sample at the same pose
        answer["yes"] = True
        page.wait_for_selector("#capture-now:not([disabled])")
        page.click("#capture-now")
        # (Playwright answers the dialog while it runs a page call: wait in the page)
        page.wait_for_selector("#messages .message:has-text('Sample #')", timeout=30000)
        page.wait_for_function(
            "document.getElementById('messages').textContent.includes('Sample #')"
            f" && !document.getElementById('messages').textContent.includes('Sample #{first_id} ')",
            timeout=30000,
        )
        wait_for(lambda: count() == 2, 10, 0.2, "the confirmed repeat")
        assert len(dialogs) == 2
        assert page.locator("#messages .message.error").count() == 0
        assert log.page_errors == [] and log.blocked_requests == []


def test_check_poses_reach_the_robot_and_a_check_asks_before_pausing_auto_capture(
    cell: Cell, result_walk: int
) -> None:
    """Item 3 (rest) and item 4: the check poses as a robot program from the page (each pose
    back from the RAPID module); starting a check while auto capture runs asks first: "no"
    leaves auto capture on and says why in words, nothing started; "yes" switches it off and
    starts the check. Runs last: the check it starts stays running."""
    from calib.programs import DOWNLOAD_FORMATS
    from calib.programs.registry import parse_program

    assert cell.daemon is not None
    url, api = cell.daemon.url, cell.daemon.client()
    walk = api.get(f"/campaigns/{result_walk}").json()  # its robot is calibrated
    rid = walk["robot_id"]
    poses = api.get(f"/robots/{rid}/check-poses").json()["poses_deg"]
    with offline_page(TABLET, allowed_origin=url) as (page, log):
        _open(page, url, "campaign")
        page.click("#campaign-list tr:has-text('result walk')")
        page.click("#tab-apply")
        page.wait_for_selector("#hold-check-downloads:not([hidden]) button[data-format=rapid]")
        shown = page.eval_on_selector_all(
            "#hold-check-downloads button", "bs => bs.map(b => b.dataset.format)"
        )
        assert shown == list(DOWNLOAD_FORMATS)
        with page.expect_download() as info:
            page.click("#hold-check-downloads button[data-format=rapid]")
        assert "check" in info.value.suggested_filename.lower()
        back = parse_program("rapid", Path(info.value.path()).read_text(encoding="utf-8"))
        assert len(back.joints_deg) == len(poses)

        # auto capture on for a campaign: a check needs it, so the page asks first
        assert api.put(f"/campaigns/{walk['id']}/auto-capture", json={"enabled": True}).is_success
        page.wait_for_timeout(1500)  # the page's next /status (every second) shows it on
        n_checks = len(api.get(f"/robots/{rid}/checks").json())
        page.once("dialog", lambda d: d.dismiss())
        page.click("#hold-check-start")
        # the check's own warning (a sensor-moved banner, also a warn, may come and go meanwhile)
        warn = page.locator("#messages .message.warn:not(#watch-banner)")
        warn.wait_for(timeout=5000)
        assert "auto capture is still on" in warn.inner_text()
        assert _axe_serious(page) == []  # the apply view with its downloads and a warning
        assert "409" not in warn.inner_text() and "POST" not in warn.inner_text()
        assert len(api.get(f"/robots/{rid}/checks").json()) == n_checks
        assert api.get("/status").json()["sampler"]["mode"] == "auto"
        # "yes": auto capture off, the check starts, the warning goes (its cause is gone)
        page.once("dialog", lambda d: d.accept())
        page.click("#hold-check-start")
        page.wait_for_function(
            "document.getElementById('hold-check-poses-note')"
            ".textContent.includes('poses captured')",
            timeout=20000,
        )
        checks = api.get(f"/robots/{rid}/checks").json()
        assert len(checks) == n_checks + 1 and checks[-1]["status"] == "running"
        warn.wait_for(state="detached", timeout=5000)
        assert page.locator("#messages .message.error").count() == 0
        assert log.page_errors == [] and log.blocked_requests == []
