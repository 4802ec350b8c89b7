"""Issue 21, the third hardening round: one regression test per defect (big ids, download names,
CSV digits and Content-Type, formula cells in exports, OPTIONS and the Allow header).

The service runs in-process with the scripted FakeSampler of test_service.py; the store is real.
"""

from __future__ import annotations

import re
import time
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any
from urllib.parse import unquote

import numpy as np
import pytest
from fastapi.testclient import TestClient
from test_service import AUTH, TOKEN, FakeSampler, _real_csv, _settings

from calib.dataset import make_samples, parse_samples_csv, samples_to_csv
from calib.models import builtin_model
from calib.synthetic import make_true_cell, noisy_lengths, random_poses_deg
from daemon.api.deps import MAX_ID
from daemon.api.http.downloads import content_disposition
from daemon.api.main import create_app

API = "/api/v1"
CSV = {**AUTH, "Content-Type": "text/csv"}


@pytest.fixture(scope="module")
def client(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TestClient]:
    app = create_app(_settings(tmp_path_factory.mktemp("h3")), TOKEN, sampler_factory=FakeSampler)
    with TestClient(app, raise_server_exceptions=False) as c:
        yield c


def _campaign(client: TestClient, robot_model: Any = "hsr-jr680") -> int:
    r = client.post(
        f"{API}/campaigns", json={"name": "c", "robot_model": robot_model}, headers=AUTH
    )
    assert r.status_code == 201, r.text
    return int(r.json()["id"])


# ------------------------------------------------------------------------ 1. ids >= 2**63
def test_every_id_path_of_every_route_answers_422_for_ids_past_sqlite(client: TestClient) -> None:
    """Walks every operation of the app (its OpenAPI schema, so a route added later is
    covered too): 2**63 and 2**64 in every ``{..._id}`` are a 422 naming the parameter, for
    every method, never a 500."""
    spec = client.get("/openapi.json").json()
    checked = 0
    for path, ops in spec["paths"].items():
        names = re.findall(r"{(\w+)}", path)
        if not names:
            continue
        assert all(n.endswith("_id") for n in names), path
        for big in (2**63, 2**64):
            url = path
            for n in names:
                url = url.replace("{" + n + "}", str(big))
            for method in ops:
                headers = CSV if url.endswith("/import") else AUTH
                r = client.request(method.upper(), url, headers=headers, content=b"{}")
                assert r.status_code == 422, (method, url, r.status_code, r.text)
                locs = [d["loc"] for d in r.json()["detail"]]
                assert ["path", names[0]] in locs, (method, url, r.text)
                checked += 1
    assert checked >= 30  # every id route, both ids, every method
    # ... and the schema says so: every path id has the bound, so clients and schemathesis know.
    for path, ops in spec["paths"].items():
        for op in ops.values():
            for p in op.get("parameters", []):
                if p["in"] == "path":
                    assert p["schema"].get("maximum") == MAX_ID, (path, p)
                    assert p["schema"].get("minimum") == 1, (path, p)


# --------------------------------------------------------------- 2. Content-Disposition
NASTY_NAMES = [
    'q"; x="y',  # a quote that would add a parameter
    "robot\r\nSet-Cookie: a=b",  # CR/LF that would end the header line
    "Ürobot 機械 \u202e",  # outside Latin-1, and a bidi control
    "back\\slash/..%2F;semi",
]


@pytest.mark.parametrize("name", NASTY_NAMES)
def test_content_disposition_is_rfc6266_with_one_filename_of_each_kind(name: str) -> None:
    value = content_disposition(f"{name}-calibrated.toml")
    value.encode("latin-1")  # a header value h11 can send (it raised for ideographs before)
    assert all(32 <= ord(c) < 127 for c in value), value
    kind, _, rest = value.partition("; ")
    assert kind == "attachment"
    # RFC 6266 parameters: token=token or token="quoted-string" (no backslash escapes used)
    params = re.findall(r'([!#$&+.^_`|~\w-]+\*?)=("[^"\\]*"|[^";\s]+)(?:; |$)', rest)
    assert "; ".join(f"{k}={v}" for k, v in params) == rest, (params, rest)
    assert [k for k, _ in params] == ["filename", "filename*"], params
    fallback, extended = params[0][1].strip('"'), params[1][1]
    assert extended.startswith("UTF-8''")
    shown = unquote(extended[len("UTF-8''") :], encoding="utf-8")
    expected = re.sub(r"[\x00-\x1f\x7f\u202e]", "", name).replace("/", "_").replace("\\", "_")
    assert shown == f"{expected}-calibrated.toml"
    assert fallback.endswith("-calibrated.toml") and '"' not in fallback and "\\" not in fallback


def test_no_route_writes_content_disposition_by_hand() -> None:
    """One helper for every download: the header's name appears in no route module."""
    routes = Path(__file__).resolve().parents[1] / "daemon" / "api" / "routes"
    for path in routes.glob("*.py"):
        assert "Content-Disposition" not in path.read_text(), path


def test_calibrated_model_download_of_a_robot_with_a_hostile_name(client: TestClient) -> None:
    """End to end: an uploaded model named with a quote, CR/LF and ideographs, identified and
    accepted; each model file downloads with a safe header naming it (a 500 or a dropped
    connection before)."""
    model = builtin_model("hsr-jr680").to_dict()
    # CR/LF in a name is refused since issue 28 (printable text only): a 422, and the
    # hostile name downloads with its quote, semicolon and ideographs.
    r = client.post(
        f"{API}/campaigns",
        json={"name": "c", "robot_model": {**model, "name": 'Zelle 3 "Süd"; x=y\r\n機械'}},
        headers=AUTH,
    )
    assert r.status_code == 422 and "robot_model.name" in r.text, r.text
    name = 'Zelle 3 "Süd"; x=y 機械'
    model["name"] = name
    cid = _campaign(client, model)
    cell = make_true_cell(builtin_model("hsr-jr680"))
    rng = np.random.default_rng(3)
    q = random_poses_deg(cell, 60, rng)
    text = samples_to_csv(make_samples(q, noisy_lengths(cell, q, rng, noise_mm=0.02)))
    assert client.post(
        f"{API}/campaigns/{cid}/samples/import", content=text, headers=CSV
    ).is_success
    job_id = client.post(
        f"{API}/campaigns/{cid}/identifications", json={"method": "lm"}, headers=AUTH
    ).json()["id"]
    deadline = time.monotonic() + 120
    while (job := client.get(f"{API}/identifications/{job_id}", headers=AUTH).json())[
        "status"
    ] not in ("succeeded", "failed"):
        assert time.monotonic() < deadline
        time.sleep(0.1)
    assert job["status"] == "succeeded", job
    if not job["accepted"]:
        assert client.post(f"{API}/identifications/{job_id}/accept", headers=AUTH).is_success
    robot_id = client.get(f"{API}/campaigns/{cid}", headers=AUTH).json()["robot_id"]
    stored = client.get(f"{API}/robots/{robot_id}", headers=AUTH).json()["name"]
    for fmt in ("toml", "urdf", "json"):
        r = client.get(f"{API}/robots/{robot_id}/calibrated-model?format={fmt}", headers=AUTH)
        assert r.status_code == 200, (fmt, r.status_code, r.text[:200])
        assert r.headers["content-disposition"] == content_disposition(f"{stored}-calibrated.{fmt}")
    r = client.get(f"{API}/identifications/{job_id}/report.html", headers=AUTH)
    assert r.status_code == 200 and r.headers["content-disposition"].startswith("inline; ")


# ------------------------------------------------------------------- 3. auto-capture race
class SlowSwitchSampler(FakeSampler):
    """The fake sampler with a switch that takes a moment, as a real one under load can: it
    widens the window in which two unserialised switches interleave."""

    def set_auto(
        self, campaign_id: int | None, anchor: str = "A", known_poses_deg: Any = None
    ) -> None:
        time.sleep(0.002)
        super().set_auto(campaign_id, anchor, known_poses_deg)


def test_parallel_auto_capture_switches_leave_db_and_sampler_agreeing(
    tmp_path_factory: pytest.TempPathFactory,
) -> None:
    """20 parallel ``PUT auto-capture {"enabled": true}`` on 20 campaigns, twice: the one
    campaign the database marks is the one the sampler captures into (in 2 of 4 trials they
    differed before)."""
    settings = _settings(tmp_path_factory.mktemp("race"))
    app = create_app(settings, TOKEN, sampler_factory=SlowSwitchSampler)
    with TestClient(app, raise_server_exceptions=False) as c:
        ids = [_campaign(c) for _ in range(20)]

        def switch(cid: int) -> int:
            r = c.put(f"{API}/campaigns/{cid}/auto-capture", json={"enabled": True}, headers=AUTH)
            return r.status_code

        for _ in range(2):
            with ThreadPoolExecutor(20) as pool:
                assert set(pool.map(switch, ids)) == {200}
            rows = c.get(f"{API}/campaigns", headers=AUTH).json()
            marked = [r["id"] for r in rows if r["auto_capture"]]
            sampler = app.state.cablecal.sampler
            assert marked == [sampler.auto_campaign_id], (marked, sampler.auto_campaign_id)


# -------------------------------------------------------------------------- 5. CSV import
@pytest.mark.parametrize(
    "digit", ["\u0667", "\uff17", "\u096d"]
)  # Arabic-Indic, fullwidth, Devanagari 7
def test_import_refuses_non_ascii_digits_naming_row_and_column(
    client: TestClient, digit: str
) -> None:
    cid = _campaign(client)
    lines = _real_csv(3).splitlines()
    cells = lines[2].split(",")
    cells[1] = digit + ".9590"  # q2 of the second data row (file line 3)
    lines[2] = ",".join(cells)
    r = client.post(f"{API}/campaigns/{cid}/samples/import", content="\n".join(lines), headers=CSV)
    assert r.status_code == 400, r.text
    detail = r.json()["detail"]
    assert detail["row"] == 3 and detail["column"] == "q2", detail
    assert "not a number" in detail["message"]
    assert client.get(f"{API}/campaigns/{cid}/samples", headers=AUTH).json() == []


def test_import_refuses_a_csv_sent_as_json_with_415(client: TestClient) -> None:
    cid = _campaign(client)
    for ctype in ("application/json", "application/x-www-form-urlencoded", None):
        headers = {**AUTH, **({"Content-Type": ctype} if ctype else {})}
        r = client.post(
            f"{API}/campaigns/{cid}/samples/import", content=_real_csv(3), headers=headers
        )
        assert r.status_code == 415, (ctype, r.text)
        assert "Content-Type: expected text/csv" in r.json()["detail"]
    assert client.get(f"{API}/campaigns/{cid}/samples", headers=AUTH).json() == []
    r = client.post(
        f"{API}/campaigns/{cid}/samples/import",
        content=_real_csv(3),
        headers={**AUTH, "Content-Type": "text/csv; charset=utf-8"},
    )
    assert r.status_code == 201, r.text


# ------------------------------------------------------------------- 6. formula injection
def test_csv_export_neutralises_formula_cells_and_reimport_restores_them(
    client: TestClient,
) -> None:
    anchors = ["=1+2", "+A", "-cmd", "@SUM(A1)", "'=quoted", "plain"]
    cid = _campaign(client)
    real = parse_samples_csv(_real_csv(len(anchors)))
    assert (real.joints_deg < 0).any()  # negative numbers to keep as numbers
    text = samples_to_csv(make_samples(real.joints_deg, real.length_mm, anchors))
    r = client.post(f"{API}/campaigns/{cid}/samples/import", content=text, headers=CSV)
    assert r.status_code == 201, r.text
    out = client.get(f"{API}/campaigns/{cid}/samples?format=csv", headers=AUTH).text
    for i, line in enumerate(out.splitlines()[1:]):
        cells = line.split(",")
        # numbers stay numbers, minus sign and all
        assert [float(c) for c in cells[:6]] == pytest.approx(real.joints_deg[i], abs=1e-6)
        assert not cells[7].startswith(("=", "+", "-", "@", "\t", "\r")), line
    assert re.search(r"(^|,)-\d", out, re.M)
    assert "'=1+2" in out and "'-cmd" in out and "''=quoted" in out and ",plain" in out
    assert list(parse_samples_csv(out).anchor) == anchors  # a re-import reverses it
    rows = client.get(f"{API}/campaigns/{cid}/samples", headers=AUTH).json()
    assert [s["anchor"] for s in rows] == anchors  # stored as sent


def test_db_export_csv_neutralises_formula_cells(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from daemon.cli import app as cli_app
    from daemon.store import Store

    db = tmp_path / "c.db"
    with Store(db) as store:
        robot = store.ensure_builtin_robot("hsr-jr680")
        cid = int(store.create_campaign("c", int(robot["id"]), "")["id"])
        real = parse_samples_csv(_real_csv(2))
        store.import_samples(
            cid, make_samples(real.joints_deg, real.length_mm, ["=HYPERLINK()", "B"])
        )
    r = CliRunner().invoke(cli_app, ["db", "export", str(cid), "--format", "csv", "--db", str(db)])
    assert r.exit_code == 0, r.output
    assert "'=HYPERLINK()" in r.output
    assert list(parse_samples_csv(r.output).anchor) == ["=HYPERLINK()", "B"]


# ------------------------------------------------------------------ 8. OPTIONS and Allow
def test_options_and_405_name_every_method_of_every_path(client: TestClient) -> None:
    """OPTIONS answers 204 with ``Allow`` on every path of the schema (405 without Allow on 6
    paths before), without the token; a method the path lacks is a 405 whose ``Allow`` lists
    every method of the path (Starlette's named only the first matching route's)."""
    spec = client.get("/openapi.json").json()
    for path, ops in spec["paths"].items():
        url = path
        for name in re.findall(r"{(\w+)}", path):
            url = url.replace("{" + name + "}", "1")
        declared = {m.upper() for m in ops}
        r = client.options(url)
        assert r.status_code == 204, (url, r.status_code, r.text)
        allow = set(r.headers["allow"].split(", "))
        assert allow - {"HEAD", "OPTIONS"} == declared, (url, allow, declared)
        missing = [m for m in ("PUT", "PATCH", "DELETE", "POST") if m not in allow]
        if missing:
            r = client.request(missing[0], url, headers=AUTH)
            assert r.status_code == 405, (missing[0], url, r.status_code)
            assert set(r.headers["allow"].split(", ")) == allow, (url, r.headers)
    assert client.options(f"{API}/no-such-thing").status_code == 404
