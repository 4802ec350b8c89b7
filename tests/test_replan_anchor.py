"""Issue 32 item 7: after a sensor move (samples on A, then on A2), a re-plan from the
campaign's samples puts its new poses on the anchor in use (``anchor_ids``: A2, where the
captures go), with every sample still informing the plan; an anchor without samples needs
its position (a 422 naming anchor_ids)."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from fastapi.testclient import TestClient
from test_service import AUTH, TOKEN, FakeSampler, _settings

from daemon.api.main import create_app
from daemon.datafiles import bundled_dataset_text


@pytest.fixture(scope="module")
def client(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TestClient]:
    app = create_app(
        _settings(tmp_path_factory.mktemp("replan")), TOKEN, sampler_factory=FakeSampler
    )
    with TestClient(app) as c:
        yield c


def _two_anchor_campaign(client: TestClient) -> int:
    r = client.post("/api/v1/campaigns", json={"name": "moved"}, headers=AUTH)
    cid = int(r.json()["id"])
    lines = bundled_dataset_text().splitlines()[:61]
    rows = [f"{lines[0]},anchor"] + [
        f"{line},{'A' if k < 40 else 'A2'}" for k, line in enumerate(lines[1:])
    ]
    r = client.post(
        f"/api/v1/campaigns/{cid}/samples/import",
        content="\n".join(rows) + "\n",
        headers={**AUTH, "Content-Type": "text/csv"},
    )
    assert r.status_code == 201, r.text
    return cid


def test_a_replan_puts_new_poses_on_the_anchor_in_use(client: TestClient) -> None:
    cid = _two_anchor_campaign(client)
    base = {"n": 6, "candidates": 200, "start_from_samples": True}
    # before (what the page sent): every anchor of the samples gets new poses
    r = client.post(f"/api/v1/campaigns/{cid}/plan", json=base, headers=AUTH)
    assert r.status_code == 201, r.text
    assert {p["anchor"] for p in r.json()["poses"]} == {"A", "A2"}
    # the page now names the anchor in use
    r = client.post(
        f"/api/v1/campaigns/{cid}/plan", json={**base, "anchor_ids": ["A2"]}, headers=AUTH
    )
    assert r.status_code == 201, r.text
    assert {p["anchor"] for p in r.json()["poses"]} == {"A2"}
    assert "60 start samples" in r.json()["summary"]["notes"][0]
    # an anchor without samples: its position is needed
    r = client.post(
        f"/api/v1/campaigns/{cid}/plan", json={**base, "anchor_ids": ["B"]}, headers=AUTH
    )
    assert r.status_code == 422 and "anchor B has no included sample" in r.text, r.text
