"""Issue 28, the fourth hardening round: one regression test per defect the API itself answers
(metric labels, non-finite numbers, control characters).

The service runs in-process with the scripted FakeSampler of test_service.py; the store is real.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient
from prometheus_client.parser import text_string_to_metric_families
from test_service import AUTH, TOKEN, FakeSampler, _settings

from daemon.api.main import create_app

API = "/api/v1"


@pytest.fixture(scope="module")
def client(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TestClient]:
    app = create_app(_settings(tmp_path_factory.mktemp("h4")), TOKEN, sampler_factory=FakeSampler)
    with TestClient(app, raise_server_exceptions=False) as c:
        yield c


# ------------------------------------------------------------- 1. closed metric labels
def _latency_labels(text: str) -> set[tuple[str, str, str]]:
    out = set()
    for family in text_string_to_metric_families(text):
        if family.name == "cablecal_http_request_duration_seconds":
            for sample in family.samples:
                lab = sample.labels
                out.add((lab["method"], lab["route"], lab["status"]))
    return out


def test_odd_methods_and_paths_do_not_grow_metrics(client: TestClient, tmp_path: Path) -> None:
    """1,000 requests with made-up methods (up to 200 bytes) and made-up paths, authorised
    and not: /metrics grows by a few label sets, not by one per request; every label is a
    known method, a route template or ``other``."""
    for path in (f"{API}/health", f"{API}/campaigns", "/metrics"):  # the usual series exist
        client.get(path, headers=AUTH)
    before = client.get("/metrics").text
    for i in range(1000):
        method = ["BREW", "X" * 200, f"M{i}", "get", "PROPFIND"][i % 5]
        path = [f"/nope/{i}", f"{API}/campaigns/{i}", f"{API}/x{i}/y", f"/static/{i}.js"][i % 4]
        client.request(method, path, headers=AUTH if i % 2 else {})
        if i % 10 == 0:  # and known methods on unknown paths
            client.get(f"/nope/{'z' * 100}{i}")
    after = client.get("/metrics").text
    growth = len(after) - len(before)
    assert growth < 30_000, (len(before), len(after))
    labels = _latency_labels(after)
    methods = {m for m, _, _ in labels}
    assert methods <= {"GET", "HEAD", "POST", "PUT", "PATCH", "DELETE", "OPTIONS", "other"}
    routes = {r for _, r, _ in labels}
    # The documented templates and the page's own routes (other tests' requests count too).
    templates = set(client.get("/openapi.json").json()["paths"])
    templates |= {"/metrics", "/static", "/", "/docs", "/openapi.json"}
    assert routes <= templates | {"other"}, routes - templates
    assert "other" in routes and "other" in methods
    assert f"{API}/campaigns/{{campaign_id}}" in routes  # the template, not the raw path
    # Another 1,000 change no size at all: every label set exists already.
    for i in range(1000, 2000):
        client.request("X" * (i % 200 + 1), f"/nope/{i}")
    assert len(client.get("/metrics").text) - len(after) < 2_000


def _campaign(client: TestClient) -> int:
    r = client.post(f"{API}/campaigns", json={"name": "c"}, headers=AUTH)
    assert r.status_code == 201, r.text
    return int(r.json()["id"])


def _post_raw(client: TestClient, path: str, text: str) -> Any:
    return client.post(path, content=text, headers={**AUTH, "Content-Type": "application/json"})


# ------------------------------------------------------------------ 5. finite numbers
@pytest.mark.parametrize("spelling", ["Infinity", "-Infinity", "NaN"])
def test_non_finite_numbers_are_refused_in_every_body_and_query(
    client: TestClient, spelling: str
) -> None:
    """``prior_mm: Infinity`` was a 202 (the stored options then showed null); now NaN and
    ±Infinity are a 422 naming the field in bodies (top level, lists, nested bodies) and in
    query parameters, and nothing is stored."""
    cid = _campaign(client)
    n_jobs = len(client.get(f"{API}/campaigns/{cid}/identifications", headers=AUTH).json())
    for field in ("prior_mm", "prior_deg", "test_fraction", "noise_mm"):
        body = f'{{"{field}": {spelling}}}'
        r = _post_raw(client, f"{API}/campaigns/{cid}/identifications", body)
        assert r.status_code == 422, (field, r.status_code, r.text)
        assert field in r.text and "finite" in r.text, r.text
    assert len(client.get(f"{API}/campaigns/{cid}/identifications", headers=AUTH).json()) == n_jobs
    q = f"[0, -60, 200, -170, 40, {spelling}]"
    r = _post_raw(client, f"{API}/campaigns/{cid}/captures", f'{{"joints_deg": {q}}}')
    assert r.status_code == 422 and "joints_deg" in r.text and "finite" in r.text, r.text
    word = {"Infinity": "inf", "-Infinity": "-Infinity", "NaN": "nan"}[spelling]
    r = client.get(f"{API}/readings", params={"since_wall_s": word}, headers=AUTH)
    assert r.status_code == 422 and "since_wall_s" in r.text and "finite" in r.text, r.text
    assert client.get(f"{API}/readings", params={"since_wall_s": "1.5"}, headers=AUTH).is_success


def test_every_number_of_every_body_schema_is_refused_when_not_finite(
    client: TestClient,
) -> None:
    """The rule is the shared body base's: every request body of the OpenAPI document whose
    schema has a number field refuses Infinity there (a model added later is covered)."""
    from daemon.api.schemas import StrictBody

    def models(cls: type) -> Iterator[type]:
        for sub in cls.__subclasses__():
            yield sub
            yield from models(sub)

    checked = 0
    for model in models(StrictBody):
        for name, field in model.model_fields.items():
            if field.annotation in (float, float | None):
                with pytest.raises(ValueError, match="finite"):
                    model.model_validate({name: float("inf")})
                checked += 1
    assert checked >= 5, checked


# --------------------------------------------------------------- 8. printable text
@pytest.mark.parametrize("char", ["\x1b", "\x07", "\r", "\n", "\x00", "\x7f", "\x85", "\x9b"])
def test_control_characters_are_refused_in_names_anchors_and_reasons(
    client: TestClient, char: str
) -> None:
    """A campaign named ``\\x1b[2J…`` was stored and cleared the terminal of ``cablecal db
    export``; C0 and C1 controls are now a 422 naming the field and the character, in
    names, anchors and reasons (notes: see the next test)."""
    cid = _campaign(client)
    bad = f"a{char}[2Jb"
    bad_notes = f"x{char}y" if char != "\n" else "\x1b"  # notes may hold line feeds
    cases = [
        ("post", f"{API}/campaigns", {"name": bad}, "name"),
        ("post", f"{API}/campaigns", {"name": "ok", "notes": bad_notes}, "notes"),
        ("post", f"{API}/campaigns/{cid}/captures", {"anchor": bad}, "anchor"),
        ("put", f"{API}/campaigns/{cid}/auto-capture", {"enabled": False, "anchor": bad}, "anchor"),
    ]
    for method, path, body, field in cases:
        r = client.request(method, path, json=body, headers=AUTH)
        assert r.status_code == 422, (path, body, r.text)
        assert field in r.text and "control character" in r.text, r.text
    names = [c["name"] for c in client.get(f"{API}/campaigns", headers=AUTH).json()]
    assert not any(char in n for n in names)
    model = client.get(f"{API}/robots/1", headers=AUTH).json()["model"]
    body = {"name": "ok", "robot_model": {**model, "name": bad}}
    r = client.post(f"{API}/campaigns", json=body, headers=AUTH)
    assert r.status_code == 422 and "robot_model.name" in r.text, r.text


def test_notes_keep_line_feeds_and_tabs(client: TestClient) -> None:
    notes = "line one\n\tline two\nline three"
    r = client.post(f"{API}/campaigns", json={"name": "noted", "notes": notes}, headers=AUTH)
    assert r.status_code == 201, r.text
    assert r.json()["notes"] == notes
    schema = client.get("/openapi.json").json()["components"]["schemas"]["CampaignCreate"]
    assert "pattern" in schema["properties"]["notes"] and "pattern" in schema["properties"]["name"]


def test_the_cli_escapes_control_characters_from_the_store(tmp_path: Path) -> None:
    """Rows written before the rule (straight into the store here) still reach the terminal
    escaped: ``\\x1b`` as text, never the byte."""
    from typer.testing import CliRunner

    from calib.dataset import make_samples
    from daemon.cli import app as cli_app
    from daemon.store import Store

    db = tmp_path / "c.db"
    with Store(db) as store:
        robot = store.ensure_builtin_robot("hsr-jr680")
        cid = int(store.create_campaign("evil\x1b[2J\x07", int(robot["id"]), "")["id"])
        q = [[0.0, -60.0, 200.0, -170.0, 40.0, 60.0]] * 2
        store.import_samples(cid, make_samples(q, [500.0, 501.0], ["\x1b]0;pwned\x07", "B"]))
    out = tmp_path / "out.csv"
    runner = CliRunner()
    for args in (["--out", str(out)], []):
        r = runner.invoke(cli_app, ["db", "export", str(cid), "--db", str(db), *args])
        assert r.exit_code == 0, r.output
        assert "\x1b" not in r.output and "\x07" not in r.output, repr(r.output)
    assert "\\x1b]0;pwned\\x07" in r.output  # the CSV on stdout, escaped
    r = runner.invoke(cli_app, ["db", "export", "evil\x1b[2J\x07", "--db", str(db)])
    assert "\x1b" not in r.output
    r = runner.invoke(cli_app, ["db", "export", "nope\x1b[2J", "--db", str(db)])
    assert r.exit_code == 2 and "\x1b" not in r.output and "nope\\x1b[2J" in r.output, r.output


def test_a_csv_import_refuses_control_characters_in_anchors(client: TestClient) -> None:
    """ESC stayed in exported anchor cells: an imported anchor is held to the same rule as
    one sent as JSON; a 400 names the file line and the column, and nothing is stored."""
    cid = _campaign(client)
    rows = ["q1,q2,q3,q4,q5,q6,L,anchor"]
    rows += [f"0,-60,200,-170,40,{60 + i},500,A" for i in range(3)]
    rows += ["", "0,-60,200,-170,40,70,500,B\x1b[2J"]
    r = client.post(
        f"{API}/campaigns/{cid}/samples/import",
        content="\n".join(rows) + "\n",
        headers={**AUTH, "Content-Type": "text/csv"},
    )
    assert r.status_code == 400, r.text
    detail = r.json()["detail"]
    assert detail["row"] == 6 and detail["column"] == "anchor", detail
    assert "control character U+001B" in detail["message"]
    assert client.get(f"{API}/campaigns/{cid}/samples", headers=AUTH).json() == []


# ------------------------------------------------- 3. what is accepted can run
def _import_anchors(client: TestClient, cid: int, counts: dict[str, int]) -> None:
    from calib.dataset import samples_to_csv
    from daemon.datafiles import read_samples

    real = read_samples(None)
    n = sum(counts.values())
    anchors = [a for a, k in counts.items() for _ in range(k)]
    sub = real.subset(np.arange(n))
    text = samples_to_csv(replace(sub, anchor=tuple(anchors)))
    r = client.post(
        f"{API}/campaigns/{cid}/samples/import",
        content=text,
        headers={**AUTH, "Content-Type": "text/csv"},
    )
    assert r.status_code == 201, r.text


def test_readiness_and_start_apply_the_same_rule_per_anchor(client: TestClient) -> None:
    """40 rows at anchor A and 2 at B: readiness said ready and POST answered 202, then the
    job failed ("anchor 'B' has 2 samples"). Now both refuse before answering, with the same
    reason naming the anchor; with enough rows at B both accept."""
    cid = _campaign(client)
    _import_anchors(client, cid, {"A": 40, "B": 2})
    ready = client.get(f"{API}/campaigns/{cid}/identification-readiness", headers=AUTH).json()
    assert ready["ready"] is False and "anchor 'B'" in ready["reason"], ready
    r = client.post(f"{API}/campaigns/{cid}/identifications", json={}, headers=AUTH)
    assert r.status_code == 409, r.text
    assert r.json()["detail"] == ready["reason"]
    assert client.get(f"{API}/campaigns/{cid}/identifications", headers=AUTH).json() == []
    cid = _campaign(client)
    _import_anchors(client, cid, {"A": 40, "B": 14})
    ready = client.get(f"{API}/campaigns/{cid}/identification-readiness", headers=AUTH).json()
    assert ready["ready"] is True and ready["reason"] is None, ready
    r = client.post(f"{API}/campaigns/{cid}/identifications", json={}, headers=AUTH)
    assert r.status_code == 202, r.text


def test_state_conflicts_are_409_with_the_reason(client: TestClient) -> None:
    """The README promises 409 for a request the schema allows but the state refuses:
    a capture with ``joints_deg`` on a robot that reports its own angles (422 before), and
    verify against a campaign without samples (422 before; needs a result: a job row with
    one is written straight into the store here)."""
    cid = _campaign(client)
    sampler = client.app.state.cablecal.sampler  # type: ignore[attr-defined]

    async def own_angles(*args: Any, **kwargs: Any) -> Any:
        raise ValueError("joints_deg: robot rob (FakeRobot) reports its own joint angles")

    original = sampler.capture
    sampler.capture = own_angles
    try:
        body = {"joints_deg": [0, -60, 200, -170, 40, 60]}
        r = client.post(f"{API}/campaigns/{cid}/captures", json=body, headers=AUTH)
    finally:
        sampler.capture = original
    assert r.status_code == 409 and "reports its own joint angles" in r.json()["detail"]
    spec = client.get("/openapi.json").json()["paths"]
    assert "409" in spec[f"{API}/campaigns/{{campaign_id}}/captures"]["post"]["responses"]
    store = client.app.state.cablecal.store  # type: ignore[attr-defined]
    robot_id = int(client.get(f"{API}/campaigns/{cid}", headers=AUTH).json()["robot_id"])
    job = store.create_job(cid, robot_id, "lm", {})
    store.save_result(int(job["id"]), {"robot": "x"}, accepted=False)
    empty = _campaign(client)
    r = client.post(
        f"{API}/identifications/{job['id']}/verify", json={"campaign_id": empty}, headers=AUTH
    )
    assert r.status_code == 409 and "no included samples" in r.json()["detail"], r.text
    assert "409" in spec[f"{API}/identifications/{{job_id}}/verify"]["post"]["responses"]
