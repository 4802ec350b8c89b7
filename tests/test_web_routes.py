"""The routes behind the operator page, in-process: the static page and /docs from local files,
/readings (live trace), /identifications/{id}/residuals and report.html, and ``cablecal
report``."""

from __future__ import annotations

import json
import math
import re
from collections import deque
from collections.abc import Iterator
from pathlib import Path
from types import SimpleNamespace
from typing import Any, ClassVar

import numpy as np
import pytest
from fastapi.testclient import TestClient
from test_service import AUTH, TOKEN, FakeSampler, _real_csv, _settings, _wait_job
from typer.testing import CliRunner

from calib.html_report import SECTIONS, sample_residuals
from calib.models import builtin_model
from daemon.api.main import create_app
from daemon.api.web import WEB_DIR
from daemon.cli import app as cli_app
from daemon.sampler.core import Sampler
from daemon.sampler.settle import PairedReading

NOW = 1_800_000_000.0


def _reading(t_wall: float, length_mm: float) -> PairedReading:
    q = (1.0, 2.0, 3.0, 4.0, 5.0, 6.0)
    return PairedReading(t_wall - 1e9, t_wall - 1e9, t_wall, q, length_mm, False, 0.0)


class TraceSampler(FakeSampler):
    """FakeSampler with a ring buffer of 10 readings 0.1 s apart, the 4th over range."""

    buffer: ClassVar[deque[PairedReading]] = deque(
        _reading(NOW + 0.1 * i, math.nan if i == 3 else 800.0 + i) for i in range(10)
    )

    def recent_readings(self, since_wall_s: float, limit: int) -> list[PairedReading]:
        return Sampler.recent_readings(SimpleNamespace(_buffer=self.buffer), since_wall_s, limit)  # type: ignore[arg-type]


@pytest.fixture(scope="module")
def client(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TestClient]:
    app = create_app(_settings(tmp_path_factory.mktemp("web")), TOKEN, sampler_factory=TraceSampler)
    with TestClient(app) as c:
        yield c


@pytest.fixture(scope="module")
def job(client: TestClient) -> dict[str, Any]:
    """An lm identification of 120 real rows (implausible, not accepted)."""
    r = client.post(
        "/api/v1/campaigns", json={"name": "w", "robot_model": "hsr-jr680"}, headers=AUTH
    )
    cid = r.json()["id"]
    client.post(
        f"/api/v1/campaigns/{cid}/samples/import",
        content=_real_csv(120),
        headers={**AUTH, "Content-Type": "text/csv"},
    )
    r = client.post(f"/api/v1/campaigns/{cid}/identifications", json={"method": "lm"}, headers=AUTH)
    done = _wait_job(client, r.json()["id"])
    assert done["status"] == "succeeded", done
    return done


# ----------------------------------------------------------------------------- page, docs
def test_page_and_its_files_are_served_from_daemon_web(client: TestClient) -> None:
    page = client.get("/")
    assert page.status_code == 200 and page.text == (WEB_DIR / "index.html").read_text()
    # Every file the page references is served, and none is on another host.
    refs = re.findall(r'(?:src|href)="([^"]+)"', page.text)
    assert refs and all(ref.startswith("/static/") for ref in refs), refs
    for ref in refs:
        assert client.get(ref).status_code == 200, ref
    js = client.get("/static/js/main.js")
    assert "javascript" in js.headers["content-type"]
    for module in (WEB_DIR / "js").glob("*.js"):
        text = module.read_text().replace('"http://www.w3.org/2000/svg"', "")  # a namespace
        assert "http://" not in text and "https://" not in text, module.name
        for imp in re.findall(r'from "(\.[^"]+)"', text):
            assert (module.parent / imp).resolve().is_file(), (module.name, imp)


def test_docs_load_swagger_ui_from_local_files(client: TestClient) -> None:
    docs = client.get("/docs").text
    assets = re.findall(r'(?:src|href)="([^"]+)"', docs)
    assert len(assets) >= 3 and all(a.startswith("/static/") for a in assets), assets
    for asset in assets:
        assert client.get(asset).status_code == 200, asset
    assert '"validatorUrl": null' in docs
    assert client.get("/redoc").status_code == 404  # it would load from a CDN


# ----------------------------------------------------------------------------- readings
def test_readings_columns_since_and_limit(client: TestClient) -> None:
    r = client.get("/api/v1/readings", headers=AUTH).json()
    assert r["t_wall_s"] == pytest.approx([NOW + 0.1 * i for i in range(10)])
    assert r["length_mm"][3] is None and r["length_mm"][4] == 804.0
    assert r["joints_deg"][0] == [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]
    newer = client.get(f"/api/v1/readings?since_wall_s={NOW + 0.65}", headers=AUTH).json()
    assert newer["length_mm"] == [807.0, 808.0, 809.0]
    last2 = client.get("/api/v1/readings?limit=2", headers=AUTH).json()
    assert last2["length_mm"] == [808.0, 809.0]  # the newest, oldest first


def test_readings_bounds_and_auth(client: TestClient) -> None:
    assert client.get("/api/v1/readings").status_code == 401
    for bad in ("limit=0", "limit=2001", "since_wall_s=-1", "since_wall_s=x"):
        assert client.get(f"/api/v1/readings?{bad}", headers=AUTH).status_code == 422, bad


# ----------------------------------------------------------------------------- results
def test_residuals_are_the_calib_residuals_of_the_included_samples(
    client: TestClient, job: dict[str, Any]
) -> None:
    r = client.get(f"/api/v1/identifications/{job['id']}/residuals", headers=AUTH)
    assert r.status_code == 200, r.text
    body = r.json()
    store = client.app.state.cablecal.store  # type: ignore[attr-defined]
    samples, ids = store.sample_set(job["campaign_id"])
    want = sample_residuals(job["result"], samples, builtin_model("hsr-jr680"))
    assert body["sample_ids"] == ids and body["n_job_samples"] == 120
    np.testing.assert_allclose(body["after_mm"], want.after_mm, rtol=0, atol=1e-12)
    assert want.before_mm is not None
    np.testing.assert_allclose(body["before_mm"], want.before_mm, rtol=0, atol=1e-12)
    rms_after = math.sqrt(np.mean(np.square(body["after_mm"])))
    assert rms_after < math.sqrt(np.mean(np.square(body["before_mm"])))


def test_report_html_of_a_job(client: TestClient, job: dict[str, Any]) -> None:
    r = client.get(f"/api/v1/identifications/{job['id']}/report.html", headers=AUTH)
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/html")
    html = r.text
    assert html.startswith("<!DOCTYPE html>") and f"identification {job['id']}" in html
    for section_id, _ in SECTIONS:
        assert f'id="{section_id}"' in html, section_id
    assert 'id="chart-residuals-before"' in html and "<script" not in html
    assert client.get(f"/api/v1/identifications/{job['id']}/report.html").status_code == 401
    assert client.get("/api/v1/identifications/999/report.html", headers=AUTH).status_code == 404


def test_no_report_while_a_job_has_no_result(client: TestClient, job: dict[str, Any]) -> None:
    store = client.app.state.cablecal.store  # type: ignore[attr-defined]
    queued = store.create_job(job["campaign_id"], job["robot_id"], "lm", {})
    for path in ("report.html", "residuals"):
        r = client.get(f"/api/v1/identifications/{queued['id']}/{path}", headers=AUTH)
        assert r.status_code == 409 and "has no result" in r.json()["detail"], r.text


# ----------------------------------------------------------------------------- CLI
def test_cli_report_writes_the_page_with_residuals(job: dict[str, Any], tmp_path: Path) -> None:
    result_path = tmp_path / "result.json"
    result_path.write_text(json.dumps(job["result"]))
    data = tmp_path / "data.csv"
    data.write_text(_real_csv(120))
    out = tmp_path / "report.html"
    run = CliRunner().invoke(
        cli_app,
        [
            "report",
            str(result_path),
            "--data",
            str(data),
            "--robot",
            "hsr-jr680",
            "--out",
            str(out),
        ],
    )
    assert run.exit_code == 0, run.output
    html = out.read_text()
    assert 'id="chart-residuals-after"' in html and "result.json" in html


def test_cli_report_bad_input_names_the_argument(tmp_path: Path) -> None:
    bad = tmp_path / "bad.json"
    bad.write_text("[1, 2]")
    out = tmp_path / "r.html"
    run = CliRunner().invoke(cli_app, ["report", str(bad), "--out", str(out)])
    assert run.exit_code == 2 and "RESULT.json" in run.output and not out.exists()
    run = CliRunner().invoke(cli_app, ["report", str(tmp_path / "none.json"), "--out", str(out)])
    assert run.exit_code == 2 and "cannot read" in run.output
