"""Issue 32, the operator's third walk, the items left after tests/test_web_walk3.py: each
walked in chromium (Playwright on Debian's /usr/bin/chromium) against the real processes (the
EMULATED cell and ``cablecal serve``): the state before, the operator's action, the state
after, with axe-core at 1366, 800 and 390 px and screenshots (bench/walk3/ when it exists).

- item 9: Fanuc frames given on the page (a frames picker, or the .toml dropped with the .ls
  files; never "unknown program dialect");
- item 4: a program of another maker's language is warned about; ``$config.dat`` is read,
  never written (not in the download); two files named ``$config.dat`` get one answer per
  file naming both, not the API's "given twice";
- item 14: the model picker offers uploaded models again and preselects the connected
  controller's maker's model, saying TOML or JSON;
- items 16, 17, 25: the filter result per file, the reasons grouped with counts that add up
  with "Keep joint targets", no Download when nothing was corrected, the previous result
  cleared by a failure, binary and empty files refused in different words, and at 390 px the
  target table shows the reason and the shift;
- item 18: the compare table says why the current calibration has no test RMSE;
- item 21: the device-errors card marks an error of a device that works again as earlier,
  with its age, without temporary-folder paths or configuration keys;
- item 23: option help in view, note figures rounded, the automatic first acceptance asks for
  a review.
"""

from __future__ import annotations

import io
import re
import zipfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from browser import offline_page, require_chromium
from test_web_walk import _axe_serious, _fits
from test_web_walk3 import _calibrate, _toml_model

from calib.dataset import make_samples, samples_to_csv
from daemon.cli.emulated import FAST_DAEMON_ENV, Cell, fast_cell_toml, wait_for

pytestmark = [pytest.mark.slow, pytest.mark.timeout(300)]

TOKEN = "web-walk4-token-0123"
SIZES = {"1366": (1366, 768), "800": (800, 1280), "390": (390, 844)}
SHOTS = Path(__file__).resolve().parent.parent / "bench" / "walk3"
PROGRAMS = Path(__file__).resolve().parent / "fixtures" / "programs"
ROBOT = "cell 8 / SN 61-0808"


@pytest.fixture(scope="module")
def cell(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Cell]:
    require_chromium()
    pytest.importorskip("axe_playwright_python", reason="the walk checks axe-core")
    work = tmp_path_factory.mktemp("web-walk4")
    toml = fast_cell_toml(n_poses=60, seed=12, move_s=0.4, dwell_s=0.8)
    with Cell(work, toml, TOKEN, FAST_DAEMON_ENV) as c:
        yield c


@pytest.fixture(scope="module")
def calibrated(cell: Cell) -> int:
    """The robot ROBOT (an HSR JR680), calibrated; its id."""
    assert cell.daemon is not None and cell.sim is not None
    return _calibrate(cell.daemon.client(), cell.sim, ROBOT)


def _shot(page: Any, tmp_path: Path, name: str) -> None:
    for folder in (tmp_path, SHOTS):
        if folder.is_dir():
            page.screenshot(path=str(folder / f"{name}.png"), full_page=True)


def _open(page: Any, url: str, view: str, campaign: str = "walk3 calibration") -> None:
    page.goto(f"{url}/#token={TOKEN}")
    page.wait_for_function("window.__cablecal && window.__cablecal.trace.updates > 0")
    page.click("#tabs button[data-view=campaign]")
    page.click(f"#campaign-list tbody tr:has-text('{campaign}')")
    page.wait_for_function(
        "(n) => document.getElementById('campaign-title').textContent.endsWith(': ' + n)",
        arg=campaign,
    )
    page.click(f"#tabs button[data-view={view}]")


def _filter(page: Any, files: list[Path]) -> str:
    """Give ``files`` to the filter card and wait for its answer: the state sentence."""
    page.wait_for_function(
        "document.getElementById('filter-target').textContent.includes('identification #')"
    )
    page.evaluate("document.getElementById('filter-state').textContent = 'waiting'")
    page.set_input_files("#filter-files", [str(f) for f in files])
    page.wait_for_function(
        "(() => { const t = document.getElementById('filter-state').textContent;"
        " return t !== 'waiting' && !t.startsWith('Filtering'); })()"
    )
    return str(page.inner_text("#filter-state"))


def _file_rows(page: Any) -> dict[str, str]:
    """The per-file table: file name -> the row's text."""
    rows = page.locator("#filter-files-result tbody tr").all()
    return {r.locator("td").first.inner_text(): r.inner_text() for r in rows}


def _counts(state: str) -> tuple[int, int, int, int]:
    m = re.match(
        r"(\d+) targets in \d+ file\(s\): (\d+) corrected, (\d+) joint target\(s\) kept, "
        r"(\d+) left unchanged",
        state,
    )
    assert m, state
    return int(m[1]), int(m[2]), int(m[3]), int(m[4])


def _reason_total(page: Any) -> int:
    items = page.locator("#filter-reasons li").all_inner_texts()
    return sum(int(re.match(r"(\d+) ×", t)[1]) for t in items)  # type: ignore[index]


def test_fanuc_frames_on_the_page_and_refusals_in_words(
    cell: Cell, calibrated: int, tmp_path: Path
) -> None:
    """Items 9, 16, 17, 25 and the maker warning of item 4."""
    assert cell.daemon is not None
    url = cell.daemon.url
    ls, frames = PROGRAMS / "fanuc" / "PICK_PART.LS", PROGRAMS / "fanuc" / "frames.toml"
    binary, empty = tmp_path / "binary.mod", tmp_path / "empty.mod"
    binary.write_bytes(bytes(range(256)) * 4)
    empty.write_bytes(b"")
    with offline_page(SIZES["1366"], allowed_origin=url) as (page, log):
        _open(page, url, "apply")
        # before: a Fanuc program without its frames: its frame targets are left, named
        state = _filter(page, [ls])
        total, corrected, kept, left = _counts(state)
        assert corrected + kept + left == total and _reason_total(page) == total - corrected
        assert "not in the frames file" in page.inner_text("#filter-reasons")
        assert "No frames file" in page.inner_text("#filter-frames-state")
        # the HSR robot is not a Fanuc: said before anything is loaded (item 4)
        warning = page.inner_text("#filter-warnings")
        assert "run on FANUC controllers" in warning and f"robot {ROBOT} is made by HSR" in warning
        # action: the frames file through its own picker
        page.evaluate("document.getElementById('filter-state').textContent = 'waiting'")
        page.set_input_files("#filter-frames", str(frames))
        page.wait_for_function(
            "document.getElementById('filter-state').textContent.includes('calibration #')"
        )
        # after: the frame targets are corrected; the counts still add up
        total2, corrected2, kept2, left2 = _counts(page.inner_text("#filter-state"))
        assert total2 == total and corrected2 > corrected
        assert corrected2 + kept2 + left2 == total2 == _reason_total(page) + corrected2
        assert "Fanuc frames from frames.toml" in page.inner_text("#filter-frames-state")
        # the frames file dropped with the programs is the frames, never a program (item 9)
        page.click("#filter-frames-clear")
        state = _filter(page, [ls, frames, PROGRAMS / "cell_a.mod", binary, empty])
        assert "unknown program dialect" not in page.inner_text("#filter-card")
        rows = _file_rows(page)
        assert "frames.toml" not in rows and f"{corrected2} of" in rows["PICK_PART.LS"]
        # item 17: a binary and an empty file, each in its own words, no "file:1:" prefix
        assert "not read: not a text file: it holds binary data" in rows["binary.mod"]
        assert "not read: empty file (0 bytes)" in rows["empty.mod"]
        assert "binary.mod:1" not in page.inner_text("#filter-card")
        assert "2 file(s) not read" in state
        assert page.is_visible("#filter-download")
        _shot(page, tmp_path, "walk4-filter-fanuc-1366")
        assert _axe_serious(page) == []
        # a failure clears the previous result (item 16): only unreadable files now
        state = _filter(page, [binary, empty])
        assert state.startswith("Nothing was filtered: 2 file(s) not read")
        assert set(_file_rows(page)) == {"binary.mod", "empty.mod"}
        assert page.is_hidden("#filter-download") and page.is_hidden("#filter-details")
        assert page.locator("#filter-reasons li").count() == 0
        assert not log.page_errors, log.page_errors
    # item 25: at 390 px the target table shows the reason and the shift
    for size in ("800", "390"):
        with offline_page(SIZES[size], allowed_origin=url) as (page, log):
            _open(page, url, "apply")
            page.set_input_files("#filter-frames", str(frames))
            _filter(page, [ls])
            page.click("#filter-details summary")
            row = page.locator("#filter-result tbody tr").first
            shown = [td.inner_text() for td in row.locator("td").all() if td.is_visible()]
            assert any("shift" in t or re.fullmatch(r"[\d.–]+", t) for t in shown), shown
            assert any("position register" in t for t in shown), shown  # its reason
            _fits(page)
            assert _axe_serious(page) == [], size
            _shot(page, tmp_path, f"walk4-filter-fanuc-{size}")
            assert not log.page_errors, log.page_errors


def test_config_dat_is_read_never_written_and_two_backups_are_answered(
    cell: Cell, calibrated: int, tmp_path: Path
) -> None:
    """Item 4: $config.dat read only and out of the download; two of them named per file."""
    assert cell.daemon is not None
    url = cell.daemon.url
    krl = sorted((PROGRAMS / "krl").iterdir())
    other = tmp_path / "backup2"
    other.mkdir()
    second = other / "$config.dat"
    second.write_bytes((PROGRAMS / "krl" / "$config.dat").read_bytes() + b"\n")
    with offline_page(SIZES["1366"], allowed_origin=url) as (page, log):
        _open(page, url, "apply")
        # before: one backup's files: $config.dat is read, never written
        state = _filter(page, krl)
        total, corrected, kept, left = _counts(state)
        assert corrected > 0 and corrected + kept + left == total
        rows = _file_rows(page)
        assert "read only" in rows["$config.dat"] and "never written" in rows["$config.dat"]
        assert "KUKA KRL programs run on KUKA controllers" in page.inner_text("#filter-warnings")
        with page.expect_download() as info:
            page.click("#filter-download")
        names = zipfile.ZipFile(io.BytesIO(Path(info.value.path()).read_bytes())).namelist()
        assert "$config.dat" not in names and "weld_seam.dat" in names, names
        # action: a second backup's $config.dat dropped with them
        state = _filter(page, [*krl, second])
        # after: one answer on each $config.dat naming both; no "given twice" from the API
        config_rows = page.locator(
            "#filter-files-result tbody tr", has_text="$config.dat"
        ).all_inner_texts()
        assert len(config_rows) == 2, rows
        for text in config_rows:
            assert "two controller backups?" in text and text.count("$config.dat (") == 2
        assert "given twice" not in page.inner_text("#filter-card")
        _shot(page, tmp_path, "walk4-filter-two-backups-1366")
        assert _axe_serious(page) == []
        # nothing corrected: no Download (item 16)
        state = _filter(page, [PROGRAMS / "krl" / "noop.src", PROGRAMS / "krl" / "noop.dat"])
        assert "nothing to download" in state and page.is_hidden("#filter-download")
        assert not log.page_errors, log.page_errors


def test_the_model_picker_offers_uploaded_models_and_the_controllers_maker(
    cell: Cell, tmp_path: Path
) -> None:
    """Item 14."""
    assert cell.daemon is not None
    url, api = cell.daemon.url, cell.daemon.client()
    toml = _toml_model(tmp_path / "irb.toml", "abb-irb4600-60-205")
    with offline_page(SIZES["1366"], allowed_origin=url) as (page, log):
        page.goto(f"{url}/#token={TOKEN}")
        page.wait_for_function("window.__cablecal && window.__cablecal.trace.updates > 0")
        page.click("#tabs button[data-view=campaign]")
        # before: the emulated controller is an HSR one: its model is preselected, and said
        page.wait_for_function(
            "document.getElementById('robot-model-note').textContent.includes('HSR')"
        )
        note = page.inner_text("#robot-model-note")
        assert "driver HuashuSocketCmdRobot" in note and "TOML or JSON" in note
        assert page.eval_on_selector("#robot-model", "e => e.value") == "hsr-jr680"
        assert api.get("/status").json()["devices"]["robot"]["maker"] == "hsr"
        # action: a robot from a TOML model file
        form = "#campaign-form"
        page.fill(f"{form} input[name=name]", "walk4 upload")
        page.fill(f"{form} input[name=robot]", "walk4 arm one")
        page.select_option("#robot-model", value="__file__")
        page.set_input_files(f"{form} input[name=robot_file]", str(toml))
        page.click(f"{form} button[type=submit]")
        page.wait_for_function(
            "document.getElementById('campaign-title').textContent.endsWith(': walk4 upload')"
        )
        # after: the uploaded model is offered again; a second arm gets it
        label = "abb-irb4600-60-205 (uploaded with robot walk4 arm one)"
        page.wait_for_selector(f"#robot-model option:text-is('{label}')", state="attached")
        assert page.eval_on_selector("#robot-model", "e => e.value") == "hsr-jr680"
        page.fill(f"{form} input[name=name]", "walk4 upload again")
        page.fill(f"{form} input[name=robot]", "walk4 arm two")
        page.select_option("#robot-model", label=label)
        page.click(f"{form} button[type=submit]")
        page.wait_for_function(
            "document.getElementById('campaign-title').textContent.endsWith('walk4 upload again')"
        )
        robots = {r["name"]: r for r in api.get("/robots").json()}
        one, two = robots["walk4 arm one"], robots["walk4 arm two"]
        assert one["id"] != two["id"] and two["model"] == one["model"]
        assert two["model_name"] == "abb-irb4600-60-205" and two["source"] == "uploaded"
        _shot(page, tmp_path, "walk4-model-picker-1366")
        assert _axe_serious(page) == []
        assert not log.page_errors, log.page_errors


def test_device_errors_say_when_and_no_paths(cell: Cell, tmp_path: Path) -> None:
    """Item 21: a link-down is shown as now while it lasts, then as earlier with its age."""
    assert cell.daemon is not None and cell.sim is not None
    url = cell.daemon.url
    with offline_page(SIZES["1366"], allowed_origin=url) as (page, log):
        page.goto(f"{url}/#token={TOKEN}")
        page.wait_for_function("window.__cablecal && window.__cablecal.trace.updates > 0")
        page.click("#tabs button[data-view=cell]")
        # before: the devices work
        page.wait_for_function(
            "document.getElementById('top-devices').textContent === 'devices connected'"
        )
        assert page.inner_text("#cell-length-stale") == ""
        # action: both links go down for 3 s
        cell.sim.control("link_down", target="all", duration_s=3.0)
        page.wait_for_function(
            "[...document.querySelectorAll('#device-errors .device-error')]"
            ".some(e => e.textContent.includes('robot: link down')"
            " && e.textContent.includes('now:'))",
            timeout=10000,
        )
        # the big length figure is marked old while no reading comes (item 27)
        page.wait_for_function(
            "document.getElementById('cell-length-stale').textContent.startsWith('old:')",
            timeout=5000,
        )
        _shot(page, tmp_path, "walk4-device-errors-now-1366")
        # after: both marked earlier, with their age; no temp folder, no reconnect countdown
        page.wait_for_function(
            "document.getElementById('top-devices').textContent === 'devices connected'",
            timeout=20000,
        )
        page.wait_for_function(
            "![...document.querySelectorAll('#device-errors .device-error')]"
            ".some(e => e.textContent.includes('now:'))"
        )
        page.wait_for_function("document.getElementById('cell-length-stale').textContent === ''")
        text = page.inner_text("#device-errors")
        assert "earlier: last at" in text and "ago" in text and "works again" in text, text
        assert "/tmp/" not in text and "next reconnect" not in text, text
        words = page.evaluate(
            "import('/static/js/cell.js').then(m => m.detailWords("
            "'gap of 0.62 s between readings (stale_s); 3 readings in 0.3 s, fewer than "
            "min_readings 5'))"
        )
        assert "stale_s" not in words and "min_readings" not in words, words
        _shot(page, tmp_path, "walk4-device-errors-earlier-1366")
        assert _axe_serious(page) == []
        assert not log.page_errors, log.page_errors


def test_a_result_is_reviewed_and_compared_in_words(
    cell: Cell, calibrated: int, tmp_path: Path
) -> None:
    """Items 18 and 23: a campaign at another sensor position (anchor A2) compared with the
    current calibration (anchor A): the '–' says why; help in view, figures rounded; the
    automatic first acceptance asks for a review."""
    assert cell.daemon is not None and cell.sim is not None
    url, api = cell.daemon.url, cell.daemon.client()
    q = np.array(cell.sim.control("poses")["poses_deg"])
    lengths = np.array(cell.sim.control("true_lengths", joints_deg=q.tolist())["lengths_mm"])
    body = {"name": "walk4 moved sensor", "robot_id": calibrated}
    c = api.post("/campaigns", json=body).json()
    csv = samples_to_csv(make_samples(q, lengths, anchor=["A2"] * len(q)))
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
    first = api.get(f"/robots/{calibrated}/calibrated-model").json()["job_id"]
    with offline_page(SIZES["1366"], allowed_origin=url) as (page, log):
        # the first calibration, made current by the daemon: the page asks for a review
        _open(page, url, "identify")
        page.click(f"#job-list tbody tr:has-text('{first}')")
        page.wait_for_selector("#result-auto-note:not([hidden])", timeout=20000)
        assert "review the figures" in page.inner_text("#result-auto-note")
        assert "review" in page.inner_text("#result-verdict")
        # option help in view, not a tooltip
        helps = page.locator("#identify-fields .option-help")
        assert helps.count() > 0 and helps.first.is_visible()
        notes = page.inner_text("#result-notes-card") if page.is_visible("#result-notes") else ""
        assert not re.search(r"\d+\.\d{5,}", notes), notes
        # before/action: the new campaign's result next to the current calibration
        page.click("#tabs button[data-view=campaign]")
        page.click("#campaign-list tbody tr:has-text('walk4 moved sensor')")
        page.click("#tabs button[data-view=identify]")
        page.wait_for_selector("#compare:not([hidden])", timeout=30000)
        # after: the '–' has its reason (item 18)
        table = page.inner_text("#compare-table")
        assert "– (see below)" in table, table
        why = page.inner_text("#compare-why")
        assert f"#{first} knows the sensor position of anchor session A only" in why, why
        assert "anchor session A2" in why and "hold check" in why
        _shot(page, tmp_path, "walk4-compare-1366")
        assert _axe_serious(page) == []
        assert not log.page_errors, log.page_errors
    for size in ("800", "390"):
        with offline_page(SIZES[size], allowed_origin=url) as (page, log):
            _open(page, url, "identify", "walk4 moved sensor")
            page.wait_for_selector("#compare-why:not([hidden])", timeout=30000)
            _fits(page)
            assert _axe_serious(page) == [], size
            _shot(page, tmp_path, f"walk4-compare-{size}")
            assert not log.page_errors, log.page_errors


def test_two_backup_folders_are_filtered_each_with_its_own_config_dat(
    cell: Cell, calibrated: int, tmp_path: Path
) -> None:
    """Item 4: two controller backups dropped as folders: each folder is its own request with
    its own $config.dat, and each gets its own Download. (A test cannot drop a folder into
    chromium: the files go in as the drop handler gives them, each with its folder.)"""
    import base64

    assert cell.daemon is not None
    url = cell.daemon.url
    krl = {p.name: base64.b64encode(p.read_bytes()).decode() for p in (PROGRAMS / "krl").iterdir()}
    with offline_page(SIZES["1366"], allowed_origin=url) as (page, log):
        _open(page, url, "apply")
        page.wait_for_function(
            "document.getElementById('filter-target').textContent.includes('identification #')"
        )
        # action: the same backup twice, as folders "KRC cell 1" and "KRC cell 2"
        page.evaluate(
            """async (files) => {
              const m = await import('/static/js/filter.js');
              const items = [];
              for (const top of ['KRC cell 1', 'KRC cell 2']) {
                for (const [name, b64] of Object.entries(files)) {
                  const bytes = Uint8Array.from(atob(b64), (c) => c.charCodeAt(0));
                  items.push({ file: new File([bytes], name), top });
                }
              }
              await m.filterPrograms(items);
            }""",
            krl,
        )
        state = page.inner_text("#filter-state")
        total, corrected, kept, left = _counts(state)
        assert corrected + kept + left == total
        # after: both $config.dat read (read only), none refused, one Download per backup
        rows = page.locator("#filter-files-result tbody tr")
        config = rows.filter(has_text="$config.dat").all_inner_texts()
        assert len(config) == 2 and all("read only" in r for r in config), config
        assert "KRC cell 1/weld_seam.dat" in page.inner_text("#filter-files-result")
        assert "two controller backups" not in page.inner_text("#filter-card")
        buttons = page.locator("#filter-downloads button.per-set").all_inner_texts()
        assert buttons == ["Download KRC cell 1: filtered", "Download KRC cell 2: filtered"]
        with page.expect_download() as info:
            page.click("#filter-downloads button.per-set >> nth=1")
        names = zipfile.ZipFile(io.BytesIO(Path(info.value.path()).read_bytes())).namelist()
        assert "$config.dat" not in names and "weld_seam.dat" in names, names
        _shot(page, tmp_path, "walk4-filter-backup-folders-1366")
        assert _axe_serious(page) == []
        assert not log.page_errors, log.page_errors


def test_rechecks_over_range_two_tabs_and_check_campaigns(
    cell: Cell, calibrated: int, tmp_path: Path
) -> None:
    """Items 19 (an indicator over range is not green), 20 (a second identification from
    another tab asks first) and 22 (a hold check's own campaign is folded in the list)."""
    assert cell.daemon is not None and cell.sim is not None
    url, api = cell.daemon.url, cell.daemon.client()
    with offline_page(SIZES["1366"], allowed_origin=url) as (page, log):
        _open(page, url, "identify")
        # item 19 before/action/after: the pill warns while the indicator is over range
        page.wait_for_function(
            "document.getElementById('top-devices').textContent === 'devices connected'"
        )
        cell.sim.control("fault", over_range=True)
        page.wait_for_function(
            "document.getElementById('top-devices').textContent.includes('over range')",
            timeout=10000,
        )
        assert "warn" in (page.get_attribute("#top-devices", "class") or "")
        cell.sim.control("fault", over_range=False)
        page.wait_for_function(
            "document.getElementById('top-devices').textContent === 'devices connected'",
            timeout=10000,
        )
        # item 20: tab B starts an identification while tab A's runs: asked, not started
        page.wait_for_selector("#identify-start:not([disabled])", timeout=20000)
        other = page.context.new_page()
        other.on("dialog", lambda d: d.dismiss())
        _open(other, url, "identify")
        other.wait_for_selector("#identify-start:not([disabled])", timeout=20000)
        campaign = _campaign_named(api, "walk3 calibration")
        before = len(api.get(f"/campaigns/{campaign}/identifications").json())
        page.select_option("#identify-form select[name=method]", "de")  # a slow one
        page.click("#identify-start")
        page.wait_for_function(
            "document.getElementById('job-state').textContent.includes('(de)')", timeout=30000
        )
        jobs = f"/campaigns/{campaign}/identifications"
        running = wait_for(
            lambda: [
                j for j in api.get(jobs).json()[before:] if j["status"] in ("queued", "running")
            ],
            30,
            0.2,
            "tab A's identification",
        )
        asked: list[str] = []
        other.once("dialog", lambda d: asked.append(d.message))
        other.click("#identify-start")
        other.wait_for_function(
            "document.getElementById('identify-need').textContent.startsWith('Not started')",
            timeout=10000,
        )
        assert asked and "still" in asked[0] and "another tab" in asked[0], asked
        assert len(api.get(jobs).json()) == before + 1  # no second one
        other.close()
        api.delete(f"/identifications/{running[0]['id']}")  # tab A's job is not needed
        page.wait_for_selector("#identify-start:not([disabled])", timeout=60000)
        # item 22: a hold check's own campaign is folded in the campaign list
        poses = api.get(f"/robots/{calibrated}/check-poses").json()["poses_deg"]
        cell_poses = cell.sim.control("poses")["poses_deg"]  # given back after the check
        cell.sim.control("load_poses", poses_deg=poses, loop=True)
        r = api.post(f"/robots/{calibrated}/checks")
        assert r.status_code == 202, r.text
        check_id, check_cid = r.json()["id"], r.json()["campaign_id"]
        wait_for(
            lambda: (
                next(
                    c for c in api.get(f"/robots/{calibrated}/checks").json() if c["id"] == check_id
                )["status"]
                != "running"
            ),
            120,
            0.5,
            f"check {check_id}",
        )
        page.click("#tabs button[data-view=campaign]")
        page.wait_for_selector("#campaign-show-checks-label:not([hidden])", timeout=10000)
        listed = page.locator("#campaign-list tbody tr td:first-child").all_inner_texts()
        assert str(check_cid) not in listed, listed
        page.check("#campaign-show-checks")
        page.wait_for_function(
            "(id) => [...document.querySelectorAll('#campaign-list tbody tr td:first-child')]"
            ".some(td => td.textContent === String(id))",
            arg=check_cid,
        )
        cell.sim.control("load_poses", poses_deg=cell_poses, loop=False)
        _shot(page, tmp_path, "walk4-rechecks-1366")
        assert _axe_serious(page) == []
        assert not log.page_errors, log.page_errors


def _campaign_named(api: Any, name: str) -> int:
    return int(next(c for c in api.get("/campaigns").json() if c["name"] == name)["id"])


def test_a_sensor_move_can_be_kept_and_banners_leave_room(cell: Cell, tmp_path: Path) -> None:
    """Item 15: the sensor-moved banner clears by Keep (the stand did move), not only by Undo;
    at 390 px the banners take at most about half the first screen."""
    from daemon.cli.emulated import FAST_CELL_NOISE_MM

    assert cell.daemon is not None and cell.sim is not None
    url, api, sim = cell.daemon.url, cell.daemon.client(), cell.sim
    n_imported = 30  # the watch's first fit
    q = np.array(sim.control("poses")["poses_deg"])
    truth = np.array(sim.control("true_lengths", joints_deg=q.tolist())["lengths_mm"])
    noisy = truth + np.random.default_rng(4).normal(0.0, FAST_CELL_NOISE_MM, truth.shape)
    name = f"walk4 bump {len(api.get('/campaigns').json()) + 1}"  # a name of its own per run
    body = {"name": name, "robot": "walk4 bump arm", "robot_model": "hsr-jr680"}
    cid = api.post("/campaigns", json=body).json()["id"]
    csv = samples_to_csv(make_samples(q[:n_imported], noisy[:n_imported]))
    r = api.post(
        f"/campaigns/{cid}/samples/import", content=csv, headers={"Content-Type": "text/csv"}
    )
    assert r.is_success, r.text
    sim.control("load_poses", poses_deg=q[n_imported:].tolist(), loop=False)
    with offline_page(SIZES["390"], allowed_origin=url) as (page, log):
        _open(page, url, "campaign", name)
        page.check("#auto-capture")
        wait_for(
            lambda: len(api.get(f"/campaigns/{cid}/samples").json()) >= n_imported + 4,
            60,
            0.2,
            "4 auto captures",
        )
        # before: the stand is bumped; the banner says so
        sim.control("move_anchor", delta_mm=[4, 0, 0])
        banner = page.locator("#watch-banner")
        mine = banner.locator(f"div[data-campaign='{cid}']")
        mine.wait_for(timeout=60000)
        height = page.evaluate("document.getElementById('messages').getBoundingClientRect().height")
        assert height <= 0.5 * SIZES["390"][1], height
        _shot(page, tmp_path, "walk4-sensor-moved-390")
        assert _axe_serious(page) == []
        # action: Keep
        mine.get_by_role("button", name="Keep: the stand moved (session A2)").click()
        # after: its banner is gone and stays gone; captures go on in session A2
        mine.wait_for(state="detached", timeout=10000)
        assert "session A2 is kept" in page.inner_text("#messages")
        page.wait_for_timeout(2500)  # a few status polls: it does not come back
        assert mine.count() == 0
        assert any(m["campaign_id"] == cid for m in api.get("/status").json()["watch"]["moves"])
        page.uncheck("#auto-capture")
        assert not log.page_errors, log.page_errors
    sim.control("move_anchor", delta_mm=[-4, 0, 0])
    sim.control("load_poses", poses_deg=q.tolist(), loop=False)  # the cell's poses back
