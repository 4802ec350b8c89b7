"""Issue 28, the fourth hardening round: one regression test per defect the API itself answers
(metric labels, non-finite numbers, control characters).

The service runs in-process with the scripted FakeSampler of test_service.py; the store is real.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

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
    templates = set(client.get("/openapi.json").json()["paths"]) | {"/metrics", "/static"}
    assert routes <= templates | {"other"}, routes - templates
    assert "other" in routes and "other" in methods
    assert f"{API}/campaigns/{{campaign_id}}" in routes  # the template, not the raw path
    # Another 1,000 change no size at all: every label set exists already.
    for i in range(1000, 2000):
        client.request("X" * (i % 200 + 1), f"/nope/{i}")
    assert len(client.get("/metrics").text) - len(after) < 2_000
