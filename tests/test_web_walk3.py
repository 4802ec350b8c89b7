"""Issue 32, the operator's third walk, page side: each silently wrong path walked in chromium
(Playwright on Debian's /usr/bin/chromium) against the real processes (the EMULATED cell and
``cablecal serve``): the state before, the operator's action, the state after, with axe-core
at 1366, 800 and 390 px and screenshots.

- item 1: a robot is a physical robot: the page makes robots with their own names, picks one
  again for its next campaign (one robot, one calibration), takes a TOML model file, and two
  arms of one model are two robots;
- item 2: a frozen controller (control port ``fault robot_frozen:true``): the page says NOT
  ready at once, Capture is refused in words, nothing is stored; captures go on after;
- items 5, 6: a check says what moved: a bumped stand is the sensor's, with its figure, and
  the check's own campaign is no sensor-move case;
- item 12: campaign rows are focusable grid rows that Enter selects;
- item 26: in forced colours the selected row, the progress bar and the active tab still show.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from browser import offline_page, require_chromium
from test_web_walk import _axe_serious, _fits

from calib.dataset import make_samples, samples_to_csv
from calib.default_robot import DEFAULT_ROBOT_MODEL
from calib.models import builtin_model
from daemon.cli.emulated import FAST_CELL_NOISE_MM, FAST_DAEMON_ENV, Cell, fast_cell_toml, wait_for

pytestmark = [pytest.mark.slow, pytest.mark.timeout(300)]

TOKEN = "web-walk3-token-0123"
SIZES = {"1366": (1366, 768), "800": (800, 1280), "390": (390, 844)}
SHOTS = Path(__file__).resolve().parent.parent / "bench" / "walk3"
FIXTURES = Path(__file__).resolve().parent / "fixtures" / "programs"
LONG_ROBOT = "Cell 7 south line, ABB IRB 4600-60/2.05 serial 4600-501234 (taught 2026)"


@pytest.fixture(scope="module")
def cell(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Cell]:
    require_chromium()
    pytest.importorskip("axe_playwright_python", reason="the walk checks axe-core")
    work = tmp_path_factory.mktemp("web-walk3")
    toml = fast_cell_toml(n_poses=60, seed=11, move_s=0.4, dwell_s=0.8)
    with Cell(work, toml, TOKEN, FAST_DAEMON_ENV) as c:
        yield c


def _shot(page: Any, tmp_path: Path, name: str) -> None:
    """A full-page screenshot in the test's folder (and in bench/walk3/ when it exists, for
    a person to look at)."""
    for folder in (tmp_path, SHOTS):
        if folder.is_dir():
            page.screenshot(path=str(folder / f"{name}.png"), full_page=True)


def _open(page: Any, url: str, view: str) -> None:
    page.goto(f"{url}/#token={TOKEN}")
    page.wait_for_function("window.__cablecal && window.__cablecal.trace.updates > 0")
    page.click(f"#tabs button[data-view={view}]")


def _toml_model(path: Path, name: str) -> Path:
    data = builtin_model(DEFAULT_ROBOT_MODEL).to_dict()
    lines = [f'name = "{name}"', f'convention = "{data["convention"]}"']
    lines.append("tool_mm = [0.0, 0.0, 0.0]")
    for joint in data["joints"]:
        lines.append("[[joints]]")
        lines += [f"{k} = {json.dumps(v)}" for k, v in joint.items()]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def _create(page: Any, name: str, **robot: str) -> None:
    """Fill and send the new-campaign form: ``pick`` (an existing robot's option label), or
    ``robot`` (a new robot's name) with ``model`` (a built-in name) or ``file`` (a path)."""
    form = "#campaign-form"
    page.fill(f"{form} input[name=name]", name)
    if "pick" in robot:
        page.select_option("#robot-pick", label=robot["pick"])
        assert page.locator("#new-robot").is_hidden()
    else:
        page.select_option("#robot-pick", value="")
        page.fill(f"{form} input[name=robot]", robot.get("robot", ""))
        if "file" in robot:
            page.select_option("#robot-model", value="__file__")
            assert "TOML or JSON" in page.inner_text("#robot-file-note")
            page.set_input_files(f"{form} input[name=robot_file]", robot["file"])
        else:
            page.select_option("#robot-model", value=robot.get("model", DEFAULT_ROBOT_MODEL))
    page.click(f"{form} button[type=submit]")
    page.wait_for_function(
        "(n) => document.getElementById('campaign-title').textContent.endsWith(': ' + n)", arg=name
    )


def _campaign(api: httpx.Client, name: str) -> dict[str, Any]:
    rows = [c for c in api.get("/campaigns").json() if c["name"] == name]
    assert len(rows) == 1, rows
    return dict(rows[0])


def test_a_robot_is_a_physical_robot_on_the_page(cell: Cell, tmp_path: Path) -> None:
    """Item 1 (and 14: a TOML model file) and item 12 (keyboard rows)."""
    assert cell.daemon is not None
    url, api = cell.daemon.url, cell.daemon.client()
    robots_before = len(api.get("/robots").json())
    toml = _toml_model(tmp_path / "irb4600.toml", "abb-irb4600-60-205")
    with offline_page(SIZES["1366"], allowed_origin=url) as (page, log):
        _open(page, url, "campaign")
        # before: the model picker offers the built-in models and a TOML or JSON file
        page.wait_for_function("document.getElementById('robot-model').options.length > 1")
        options = page.locator("#robot-model option").all_inner_texts()
        assert f"{DEFAULT_ROBOT_MODEL} (HSR JR680)" in options  # the built-in's maker, title
        assert "From a model file (.toml or .json) …" in options
        # action: two arms of one model, then the first one again for its next campaign
        _create(page, "walk3 first", robot="cell 4 / SN 61-0042", model=DEFAULT_ROBOT_MODEL)
        assert "robot cell 4 / SN 61-0042 (model hsr-jr680)" in page.inner_text("#campaign-counts")
        _create(page, "walk3 second arm", robot="cell 5 / SN 61-0077", model=DEFAULT_ROBOT_MODEL)
        page.wait_for_function(
            "[...document.querySelectorAll('#robot-pick option')]"
            ".some(o => o.text.startsWith('cell 5'))"
        )
        _create(page, "walk3 first again", pick=f"cell 4 / SN 61-0042 ({DEFAULT_ROBOT_MODEL})")
        # a TOML model file, twice under one robot name: one robot
        _create(page, "walk3 irb", robot=LONG_ROBOT, file=str(toml))
        _create(page, "walk3 irb again", robot=LONG_ROBOT, file=str(toml))
        _fits(page)  # a long robot name in the picker widened the page before
        _shot(page, tmp_path, "walk3-robots-1366")
        # after: the API agrees
        first, second = _campaign(api, "walk3 first"), _campaign(api, "walk3 second arm")
        again = _campaign(api, "walk3 first again")
        irb, irb_again = _campaign(api, "walk3 irb"), _campaign(api, "walk3 irb again")
        assert first["robot_id"] != second["robot_id"]
        assert again["robot_id"] == first["robot_id"] and irb_again["robot_id"] == irb["robot_id"]
        assert irb["robot_model_name"] == "abb-irb4600-60-205" and irb["robot_name"] == LONG_ROBOT
        assert len(api.get("/robots").json()) == robots_before + 3
        # item 12: the campaign rows are grid rows a keyboard selects
        assert page.get_attribute("#campaign-list", "role") == "grid"
        row = page.locator("#campaign-list tbody tr", has_text="walk3 second arm")
        assert row.get_attribute("tabindex") == "0"
        row.focus()
        page.keyboard.press("Enter")
        page.wait_for_function(
            "document.getElementById('campaign-title').textContent.endsWith(': walk3 second arm')"
        )
        # the list redraws after the title: wait for the selected row (fails if never selected)
        page.wait_for_function(
            "[...document.querySelectorAll('#campaign-list tbody tr')].some(r =>"
            " r.textContent.includes('walk3 second arm')"
            " && r.getAttribute('aria-selected') === 'true')",
            timeout=10000,
        )
        assert _axe_serious(page) == []
        assert not log.page_errors, log.page_errors
    # long names at 800 and 390 px: no sideways scroll, axe clean
    for size in ("800", "390"):
        with offline_page(SIZES[size], allowed_origin=url) as (page, log):
            _open(page, url, "campaign")
            page.wait_for_function("document.getElementById('robot-pick').options.length > 3")
            page.click("#campaign-list tbody tr:has-text('walk3 irb again')")
            page.wait_for_function(
                "document.getElementById('campaign-title').textContent.endsWith('walk3 irb again')"
            )
            _fits(page)
            assert _axe_serious(page) == [], size
            _shot(page, tmp_path, f"walk3-robots-{size}")
            assert not log.page_errors, log.page_errors


def _sampler(api: httpx.Client) -> dict[str, Any]:
    return dict(api.get("/status").json()["sampler"])


def test_a_frozen_controller_gives_no_sample(cell: Cell, tmp_path: Path) -> None:
    """Item 2 on the emulated cell: frozen joints while the robot moves."""
    assert cell.daemon is not None and cell.sim is not None
    url, api = cell.daemon.url, cell.daemon.client()
    cid = api.post(
        "/campaigns", json={"name": "walk3 frozen", "robot": "cell 9", "robot_model": "hsr-jr680"}
    ).json()["id"]
    cell.sim.control("hold", on=True)
    wait_for(lambda: _sampler(api)["settled"], 20, 0.2, "a settled robot")
    with offline_page(SIZES["1366"], allowed_origin=url) as (page, log):
        _open(page, url, "campaign")
        page.click("#campaign-list tbody tr:has-text('walk3 frozen')")
        page.wait_for_function(
            "document.getElementById('campaign-title').textContent.endsWith('walk3 frozen')"
        )
        # before: ready, no warning where Capture is pressed
        assert "NOT ready" not in page.inner_text("#capture-state")
        # action: the controller freezes, the robot goes on to its next poses
        cell.sim.control("fault", robot_frozen=True)
        cell.sim.control("hold", on=False)
        wait_for(lambda: _sampler(api)["settle_state"] == "frozen", 30, 0.1, "the frozen verdict")
        page.wait_for_function(
            "document.getElementById('capture-state').textContent.includes('NOT ready')",
            timeout=5000,
        )
        assert "bad" in (page.get_attribute("#capture-state", "class") or "")
        page.wait_for_function(
            "document.getElementById('top-devices').textContent.includes('joints frozen')"
        )
        cell.sim.control("hold", on=True)  # the robot stops at a pose: the old wrong sample
        n_before = len(api.get(f"/campaigns/{cid}/samples").json())
        page.click("#capture-now")
        page.wait_for_selector(".message.error", timeout=15000)
        message = page.inner_text(".message.error")
        assert "not updating its joints" in message, message
        r = api.post(f"/campaigns/{cid}/captures", json={"anchor": "A"})
        assert r.status_code == 503 and r.json()["detail"]["reason"] == "frozen", r.text
        assert len(api.get(f"/campaigns/{cid}/samples").json()) == n_before  # nothing stored
        _shot(page, tmp_path, "walk3-frozen-1366")
        assert _axe_serious(page) == []
        page.click("#tabs button[data-view=cell]")
        page.wait_for_function(
            "document.getElementById('cell-sampler').textContent.includes('stopped changing')"
        )
        _shot(page, tmp_path, "walk3-frozen-cell-1366")
        # after: the controller answers again; the page says ready, a capture is stored
        cell.sim.control("fault", robot_frozen=False)
        wait_for(lambda: _sampler(api)["settled"], 20, 0.2, "settled again")
        page.wait_for_function(
            "!document.getElementById('cell-sampler').textContent.includes('stopped changing')"
        )
        r = api.post(f"/campaigns/{cid}/captures", json={"anchor": "A"})
        assert r.status_code == 201, r.text
        assert not log.page_errors, log.page_errors
    cell.sim.control("hold", on=False)


def _calibrate(api: httpx.Client, sim: Any, robot: str) -> int:
    """A calibrated robot: the cell's true lengths at its poses (+ seeded noise) imported,
    identified with lm and accepted; its robot id."""
    q = np.array(sim.control("poses")["poses_deg"])
    truth = np.array(sim.control("true_lengths", joints_deg=q.tolist())["lengths_mm"])
    lengths = truth + np.random.default_rng(5).normal(0.0, FAST_CELL_NOISE_MM, truth.shape)
    body = {"name": "walk3 calibration", "robot": robot, "robot_model": DEFAULT_ROBOT_MODEL}
    c = api.post("/campaigns", json=body).json()
    csv = samples_to_csv(make_samples(q, lengths))
    r = api.post(
        f"/campaigns/{c['id']}/samples/import",
        content=csv,
        headers={"Content-Type": "text/csv"},
    )
    assert r.is_success, r.text
    job = api.post(f"/campaigns/{c['id']}/identifications", json={"method": "lm"}).json()["id"]
    wait_for(
        lambda: api.get(f"/identifications/{job}").json()["status"] == "succeeded", 120, 0.5, "lm"
    )
    if not api.get(f"/identifications/{job}").json()["current"]:
        assert api.post(f"/identifications/{job}/accept").is_success
    return int(c["robot_id"])


@pytest.fixture(scope="module")
def calibrated(cell: Cell) -> int:
    """The robot "cell 3 / SN 61-0101", calibrated (a fixture: each test runs alone too)."""
    assert cell.daemon is not None and cell.sim is not None
    return _calibrate(cell.daemon.client(), cell.sim, "cell 3 / SN 61-0101")


def test_a_check_says_the_sensor_stand_moved(cell: Cell, calibrated: int, tmp_path: Path) -> None:
    """Items 5 and 6: a bumped stand (30 mm) is reported as the sensor's, with its figure,
    never as a robot change; the check's own campaign gets no sensor-moved case of its own."""
    assert cell.daemon is not None and cell.sim is not None
    url, api = cell.daemon.url, cell.daemon.client()
    robot_id = calibrated
    poses = api.get(f"/robots/{robot_id}/check-poses").json()["poses_deg"]
    # action: the stand is bumped by 30 mm, then a check runs
    shift = [24.5, -15.0, 10.2]
    cell.sim.control("move_anchor", delta_mm=shift)
    cell.sim.control("load_poses", poses_deg=poses, loop=True)
    r = api.post(f"/robots/{robot_id}/checks")
    assert r.status_code == 202, r.text
    check_id, check_cid = r.json()["id"], r.json()["campaign_id"]

    def finished() -> dict[str, Any] | None:
        row = next(c for c in api.get(f"/robots/{robot_id}/checks").json() if c["id"] == check_id)
        return None if row["status"] == "running" else dict(row)

    check = wait_for(finished, 120, 0.5, f"check {check_id}")
    assert check["status"] == "not_held" and check["error"] is None, check
    cause = api.get("/status").json()["hold_check"]["cause"]
    size = float(np.linalg.norm(shift))
    assert cause["kind"] == "sensor" and cause["shift_mm"] == pytest.approx(size, abs=3.0)
    assert cause["text"].startswith("the sensor stand moved by")
    # the check's campaign is no sensor-move case (item 5): no move, no anchor split
    watch = api.get("/status").json()["watch"]
    assert all(m["campaign_id"] != check_cid for m in watch["moves"]), watch
    assert api.get(f"/campaigns/{check_cid}").json()["anchors"] == ["A"]
    with offline_page(SIZES["1366"], allowed_origin=url) as (page, log):
        _open(page, url, "campaign")
        page.click("#campaign-list tbody tr:has-text('walk3 calibration')")
        page.click("#tabs button[data-view=apply]")
        page.wait_for_function(
            "document.getElementById('hold-check-state').textContent.startsWith('SENSOR MOVED')"
        )
        words = page.inner_text("#hold-check-state")
        assert "The sensor stand moved by" in words and "check the stand" in words, words
        assert "Calibrate the robot again" not in words
        assert "bad" in (page.get_attribute("#hold-check-state", "class") or "")
        assert page.inner_text("#top-hold-check").startswith("sensor moved (check #")  # item 22
        _shot(page, tmp_path, "walk3-check-sensor-1366")
        assert _axe_serious(page) == []
        assert not log.page_errors, log.page_errors
    cell.sim.control("move_anchor", delta_mm=[-v for v in shift])


def test_the_filter_download_is_what_was_shown(cell: Cell, calibrated: int, tmp_path: Path) -> None:
    """Items 3, 4 (the robot and calibration named before the drop, joint targets kept by
    default), 10 (a bad file does not block the good one), 16 (per-file result, reasons
    grouped): tab A previews with calibration #1, tab B accepts #2, tab A's Download is
    refused in words instead of returning other numbers."""
    assert cell.daemon is not None
    url, api = cell.daemon.url, cell.daemon.client()
    program = FIXTURES / "cell_a.mod"
    bad = tmp_path / "bad.mod"
    bad.write_text("MODULE B\n  CONST robtarget p:=[[1,2],[1,0,0,0]];\nENDMODULE\n")
    first = api.get(f"/robots/{calibrated}/calibrated-model").json()["job_id"]
    with offline_page(SIZES["1366"], allowed_origin=url) as (page, log):
        _open(page, url, "campaign")
        page.click("#campaign-list tbody tr:has-text('walk3 calibration')")
        page.click("#tabs button[data-view=apply]")
        # before: whose programs, with which calibration, said before the drop
        page.wait_for_function(
            "document.getElementById('filter-target').textContent.includes('identification #')"
        )
        target = page.inner_text("#filter-target")
        assert "robot cell 3 / SN 61-0101 (model hsr-jr680)" in target
        assert f"identification #{first} of" in target
        assert page.is_checked("#filter-keep-joints")  # taught points stay by default
        # action: a good and a bad file dropped together
        page.set_input_files("#filter-files", [str(program), str(bad)])
        page.wait_for_function(
            "document.getElementById('filter-state').textContent.includes('calibration #')"
        )
        state = page.inner_text("#filter-state")
        assert f"calibration #{first}" in state and "1 file(s) not read" in state, state
        files = page.inner_text("#filter-files-result")
        assert "cell_a.mod" in files and "not read: line 2:" in files
        assert files.count("bad.mod") == 1  # one row: its name, then its reason with the line
        assert "joint targets kept" in page.inner_text("#filter-reasons")
        assert page.is_visible("#filter-download")
        _shot(page, tmp_path, "walk3-filter-preview-1366")
        assert _axe_serious(page) == []
        # tab B accepts another calibration of the robot
        campaign = next(c for c in api.get("/campaigns").json() if c["name"] == "walk3 calibration")
        job = api.post(
            f"/campaigns/{campaign['id']}/identifications", json={"method": "lm", "seed": 4}
        ).json()["id"]
        wait_for(
            lambda: api.get(f"/identifications/{job}").json()["status"] == "succeeded",
            120,
            0.5,
            "the second identification",
        )
        if not api.get(f"/identifications/{job}").json()["current"]:
            assert api.post(f"/identifications/{job}/accept").is_success
        # after: tab A's Download is refused, in words, and offered no more
        page.click("#filter-download")
        page.wait_for_function(
            "document.getElementById('filter-state').textContent.startsWith('Not downloaded')"
        )
        words = page.inner_text("#filter-state")
        assert f"#{first} was shown, #{job} of" in words and "preview the files again" in words
        assert page.is_hidden("#filter-download")
        page.wait_for_function(
            f"document.getElementById('filter-target').textContent.includes('#{job} of')"
        )
        _shot(page, tmp_path, "walk3-filter-refused-1366")
        # the preview again names the new calibration; its download is the shown files
        page.set_input_files("#filter-files", [str(program)])
        page.wait_for_function(
            f"document.getElementById('filter-state').textContent.includes('calibration #{job}')"
        )
        with page.expect_download() as info:
            page.click("#filter-download")
        assert info.value.suggested_filename == "cell_a.mod"
        assert not log.page_errors, log.page_errors


def test_an_acceptance_is_undone_with_one_button(
    cell: Cell, calibrated: int, tmp_path: Path
) -> None:
    """Item 13: Accept replaces the robot's calibration; one Undo button makes the replaced
    one current again, and the undone result stays listed."""
    assert cell.daemon is not None
    url, api = cell.daemon.url, cell.daemon.client()
    before = api.get(f"/robots/{calibrated}/calibrated-model").json()["job_id"]
    campaign = next(c for c in api.get("/campaigns").json() if c["name"] == "walk3 calibration")
    with offline_page(SIZES["1366"], allowed_origin=url) as (page, log):
        page.on("dialog", lambda d: d.accept())
        _open(page, url, "campaign")
        page.click("#campaign-list tbody tr:has-text('walk3 calibration')")
        page.click("#tab-identify")
        page.wait_for_selector("#identify-start:not([disabled])", timeout=20000)
        page.select_option("#identify-form select[name=method]", "lm")
        page.click("#identify-start")
        page.wait_for_selector("#compare:not([hidden])", timeout=120000)
        new = api.get(f"/campaigns/{campaign['id']}/identifications").json()[-1]["id"]
        assert page.is_hidden("#accept-undo")
        # action: Accept, then Undo
        page.click("#accept")
        page.wait_for_selector("#accept-undo:not([hidden])")
        assert f"#{new} replaced calibration #{before}" in page.inner_text("#accept-undo")
        assert api.get(f"/robots/{calibrated}/calibrated-model").json()["job_id"] == new
        _shot(page, tmp_path, "walk3-undo-offered-1366")
        assert _axe_serious(page) == []
        page.click("#accept-undo-button")
        page.wait_for_selector("#accept-undo", state="hidden")
        # after: the replaced calibration is current again, the undone one stays listed
        assert api.get(f"/robots/{calibrated}/calibrated-model").json()["job_id"] == before
        listed = {
            j["id"]: j for j in api.get(f"/campaigns/{campaign['id']}/identifications").json()
        }
        assert new in listed and not listed[new]["current"]
        page.wait_for_selector("#accept:not([hidden])")  # it can be accepted again
        assert not log.page_errors, log.page_errors


def _escape_every_ask(page: Any) -> None:
    """Press Escape on the token dialog until it stays closed (a 401 may ask once more)."""
    for _ in range(4):
        page.wait_for_timeout(800)
        if page.evaluate("document.getElementById('token-dialog').open"):
            page.keyboard.press("Escape")
    assert not page.evaluate("document.getElementById('token-dialog').open")


def test_the_token_dialog_never_strands_the_page(cell: Cell, tmp_path: Path) -> None:
    """Item 11: Escape on the token dialog, and a 401, leave the "token" button working; the
    right token then brings the page back without a reload."""
    assert cell.daemon is not None
    url, api = cell.daemon.url, cell.daemon.client()
    api.post("/campaigns", json={"name": "walk3 token", "robot_model": DEFAULT_ROBOT_MODEL})
    for start in (f"{url}/", f"{url}/#token=wrong-token-0000"):
        with offline_page(SIZES["390"], allowed_origin=url) as (page, log):
            # before: no token (or a refused one): the dialog asks
            page.goto(start)
            page.wait_for_selector("#token-dialog[open]")
            # action: Escape (every time it asks), then the "token" button
            _escape_every_ask(page)
            page.click("#token-button")
            page.wait_for_selector("#token-dialog[open]")
            _shot(page, tmp_path, "walk3-token-dialog-390")
            page.fill("#token-input", TOKEN)
            page.keyboard.press("Enter")
            # after: the page runs: readings arrive, the campaigns are listed
            page.wait_for_function("window.__cablecal.trace.updates > 0", timeout=15000)
            page.click("#tabs button[data-view=campaign]")
            page.wait_for_selector("#campaign-list tbody tr:has-text('walk3 token')", timeout=15000)
            assert not page.evaluate("document.getElementById('token-dialog').open")
            assert not log.page_errors, log.page_errors


def test_forced_colours_keep_the_selection_visible(cell: Cell, tmp_path: Path) -> None:
    """Item 26: with forced colours (high contrast) backgrounds go; the selected campaign row,
    the progress bar and the active tab keep a system colour of their own."""
    assert cell.daemon is not None
    url, api = cell.daemon.url, cell.daemon.client()
    api.post("/campaigns", json={"name": "walk3 contrast", "robot_model": DEFAULT_ROBOT_MODEL})
    with offline_page(SIZES["1366"], allowed_origin=url) as (page, log):
        page.emulate_media(forced_colors="active")
        _open(page, url, "campaign")
        page.click("#campaign-list tbody tr:has-text('walk3 contrast')")
        page.wait_for_selector("#campaign-list tbody tr[aria-selected=true]")
        # the list redraws every few seconds: read the style of the row selected at that moment
        # (a row read as it is replaced has no computed style)
        page.wait_for_function(
            """() => {
              const e = document.querySelector('#campaign-list tbody tr[aria-selected=true]');
              return e !== null && e.isConnected && getComputedStyle(e).outlineStyle === 'solid';
            }""",
            timeout=5000,
        )
        bar = page.eval_on_selector(".progress", "e => getComputedStyle(e).borderTopStyle")
        assert bar == "solid"
        tab = page.eval_on_selector("#tab-campaign", "e => getComputedStyle(e).textDecorationLine")
        assert tab == "underline"
        _shot(page, tmp_path, "walk3-forced-colours-1366")
        assert not log.page_errors, log.page_errors
