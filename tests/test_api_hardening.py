"""Issue 11, reliability hardening of the REST API: one regression test per defect the probe of
the running daemon found (500s, lax validation, unbounded bodies and lists, a half-applied
auto-capture switch, the error contract).

The service runs in-process (TestClient runs the lifespan) with the scripted FakeSampler of
test_service.py; the store is real.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient
from pydantic import ValidationError
from test_service import AUTH, TOKEN, FakeSampler, _campaign, _real_csv, _sampler, _settings

from daemon.api.deps import MAX_ID
from daemon.api.main import create_app
from daemon.config import Settings

BIG = 2**63  # one past SQLite's largest INTEGER
CSV = {**AUTH, "Content-Type": "text/csv"}


@pytest.fixture(scope="module")
def client(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TestClient]:
    app = create_app(_settings(tmp_path_factory.mktemp("hard")), TOKEN, sampler_factory=FakeSampler)
    with TestClient(app, raise_server_exceptions=False) as c:
        yield c


def _is_validation_list(body: Any) -> bool:
    """The 422 shape: ``{"detail": [{"loc": [...], "msg": str, "type": str}, ...]}``."""
    detail = body.get("detail") if isinstance(body, dict) else None
    return (
        isinstance(detail, list)
        and len(detail) > 0
        and all(
            isinstance(d.get("loc"), list) and isinstance(d.get("msg"), str) and "type" in d
            for d in detail
        )
    )


# ---------------------------------------------------------------------------- 1. no 500s
def test_ids_beyond_sqlite_integer_are_422_on_every_id_route(client: TestClient) -> None:
    cases = [
        ("GET", f"/api/v1/campaigns/{BIG}", None),
        ("GET", f"/api/v1/campaigns/{BIG}/samples", None),
        ("POST", f"/api/v1/campaigns/{BIG}/captures", {}),
        ("PUT", f"/api/v1/campaigns/{BIG}/auto-capture", {"enabled": False}),
        ("POST", f"/api/v1/campaigns/{BIG}/identifications", {}),
        ("GET", f"/api/v1/campaigns/{BIG}/identifications", None),
        ("PATCH", f"/api/v1/samples/{BIG}", {"excluded": True}),
        ("GET", f"/api/v1/identifications/{BIG}", None),
        ("DELETE", f"/api/v1/identifications/{BIG}", None),
        ("POST", f"/api/v1/identifications/{BIG}/accept", None),
        ("GET", f"/api/v1/robots/{BIG}", None),
        ("GET", f"/api/v1/robots/{BIG}/calibrated-model", None),
        ("GET", f"/api/v1/events?since_id={BIG}", None),
    ]
    for method, url, body in cases:
        r = client.request(method, url, json=body, headers=AUTH)
        assert r.status_code == 422, (method, url, r.status_code, r.text)
        assert _is_validation_list(r.json()), r.text
    r = client.post(f"/api/v1/campaigns/{BIG}/samples/import", content="q1\n", headers=CSV)
    assert r.status_code == 422, r.text
    # The largest id is valid: a plain 404.
    assert client.get(f"/api/v1/campaigns/{MAX_ID}", headers=AUTH).status_code == 404
    assert client.get(f"/api/v1/campaigns/{MAX_ID + 1}", headers=AUTH).status_code == 422


@pytest.mark.parametrize("name", ["", " ", "\n\t", "\ud800", "a\udfffb"])
def test_blank_or_unpaired_surrogate_names_are_422(client: TestClient, name: str) -> None:
    body = json.dumps({"name": name})  # json.dumps escapes a lone surrogate as \\ud800
    r = client.post(
        "/api/v1/campaigns", content=body, headers={**AUTH, "Content-Type": "application/json"}
    )
    assert r.status_code == 422, r.text
    assert _is_validation_list(r.json()) and r.json()["detail"][0]["loc"][:2] == ["body", "name"]


@pytest.mark.parametrize("anchor", [" ", "\n", "", "\ud800"])
def test_auto_capture_with_a_blank_anchor_changes_nothing(client: TestClient, anchor: str) -> None:
    a, b = _campaign(client, "anchor-a"), _campaign(client, "anchor-b")
    url = "/api/v1/campaigns/{}/auto-capture"
    assert client.put(url.format(a), json={"enabled": True}, headers=AUTH).status_code == 200
    body = json.dumps({"enabled": True, "anchor": anchor})
    r = client.put(
        url.format(b), content=body, headers={**AUTH, "Content-Type": "application/json"}
    )
    assert r.status_code == 422 and _is_validation_list(r.json()), r.text
    # Neither the sampler nor the database moved: still auto on campaign a, with anchor A.
    assert _sampler(client).auto == a
    assert client.get(f"/api/v1/campaigns/{a}", headers=AUTH).json()["auto_capture"] is True
    got_b = client.get(f"/api/v1/campaigns/{b}", headers=AUTH).json()
    assert got_b["auto_capture"] is False and got_b["auto_anchor"] == "A"
    client.put(url.format(a), json={"enabled": False}, headers=AUTH)


def test_auto_capture_rolls_back_whole_when_the_sampler_refuses(client: TestClient) -> None:
    a, b = _campaign(client, "rb-a"), _campaign(client, "rb-b")
    url = "/api/v1/campaigns/{}/auto-capture"
    assert client.put(url.format(a), json={"enabled": True, "anchor": "P"}, headers=AUTH).is_success
    fake = _sampler(client)
    real_set_auto = fake.set_auto
    calls: list[Any] = []

    def refuse_b(campaign_id: int | None, anchor: str = "A", known_poses_deg: Any = None) -> None:
        calls.append((campaign_id, anchor))
        if campaign_id == b:
            raise ValueError("sampler refused")
        real_set_auto(campaign_id, anchor, known_poses_deg)

    fake.set_auto = refuse_b  # type: ignore[method-assign]
    try:
        r = client.put(url.format(b), json={"enabled": True}, headers=AUTH)
    finally:
        fake.set_auto = real_set_auto  # type: ignore[method-assign]
    assert r.status_code == 503 and "sampler" in r.json()["detail"], r.text
    assert fake.auto == a and calls[-1] == (a, "P")  # the sampler is back on a
    got = {c: client.get(f"/api/v1/campaigns/{c}", headers=AUTH).json() for c in (a, b)}
    assert got[a]["auto_capture"] is True and got[a]["auto_anchor"] == "P"
    assert got[b]["auto_capture"] is False
    client.put(url.format(a), json={"enabled": False}, headers=AUTH)


def test_csv_with_a_bare_cr_or_a_huge_field_is_400_naming_the_row(client: TestClient) -> None:
    cid = _campaign(client, "csv-500")
    url = f"/api/v1/campaigns/{cid}/samples/import"
    good = _real_csv(3)
    lines = good.splitlines()
    bare_cr = "\n".join([lines[0], lines[1], lines[2] + "\r" + lines[3]]) + "\n"
    r = client.post(url, content=bare_cr, headers=CSV)
    assert r.status_code == 400 and r.json()["detail"]["row"] == 3, r.text
    huge = good + "1,2,3,4,5,6,7,A" + "x" * 140_000 + "\n"
    r = client.post(url, content=huge, headers=CSV)
    assert r.status_code == 400 and r.json()["detail"]["row"] == 5, r.text
    assert "field" in r.json()["detail"]["message"]
    assert client.get(f"/api/v1/campaigns/{cid}/samples", headers=AUTH).json() == []


# ---------------------------------------------------------------------------- 2. strictness
@pytest.mark.parametrize(
    ("csv_text", "row", "needle"),
    [
        ("q1,q2,q3,q4,q5,q6,L,Q1\n0,0,0,0,0,0,500,9\n", 1, "duplicated column"),
        ("q1,q2,q3,q4,q5,q6,L,length_mm\n0,0,0,0,0,0,500,600\n", 1, "both"),
        ("q1,q2,q3,q4,q5,q6,L\n0,1_0,0,0,0,0,500\n", 2, "not a number"),
        ("q1,q2,q3,q4,q5,q6,L\n0,0,0,0,0,0,5_00\n", 2, "not a number"),
    ],
)
def test_csv_parser_is_strict(client: TestClient, csv_text: str, row: int, needle: str) -> None:
    cid = _campaign(client, "csv-strict")
    r = client.post(f"/api/v1/campaigns/{cid}/samples/import", content=csv_text, headers=CSV)
    assert r.status_code == 400, r.text
    assert r.json()["detail"]["row"] == row and needle in r.json()["detail"]["message"], r.text


def test_booleans_are_strict(client: TestClient) -> None:
    cid = _campaign(client, "strict-bool")
    for value in ("yes", "true", 1, "on"):
        r = client.put(
            f"/api/v1/campaigns/{cid}/auto-capture", json={"enabled": value}, headers=AUTH
        )
        assert r.status_code == 422 and "enabled" in r.text, (value, r.text)
    assert _sampler(client).auto != cid
    assert client.get(f"/api/v1/campaigns/{cid}", headers=AUTH).json()["auto_capture"] is False


def test_seed_must_be_non_negative(client: TestClient) -> None:
    import numpy as np

    from calib.dataset import make_samples
    from calib.options import IdentifyOptions, OptionError, validate

    cid = _campaign(client, "seed")
    for seed in (-1, 2**32, 2**70):
        r = client.post(
            f"/api/v1/campaigns/{cid}/identifications", json={"seed": seed}, headers=AUTH
        )
        assert r.status_code == 422 and "seed" in r.text, (seed, r.text)
    with pytest.raises(OptionError, match="seed"):
        validate(make_samples(np.zeros((30, 6)), np.full(30, 500.0)), IdentifyOptions(seed=-1))


def test_a_short_token_is_a_config_error(tmp_path: Path) -> None:
    with pytest.raises(ValidationError, match=r"api_token[\s\S]*at least 16"):
        Settings(state_dir=tmp_path, api_token="x")
    with pytest.raises(ValidationError, match="api_token"):
        Settings(state_dir=tmp_path, api_token="x" * 15)
    assert Settings(state_dir=tmp_path, api_token="x" * 16).api_token is not None
