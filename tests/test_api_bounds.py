"""Issue 11, bounded resources and the error contract of the REST API: auth before the body,
body limits enforced while the body streams, length limits, paginated lists, imports off the
event loop, every 4xx in one shape and declared in OpenAPI.
"""

from __future__ import annotations

import asyncio
import statistics
import threading
import time
from collections.abc import Iterator
from typing import Any

import pytest
from fastapi.testclient import TestClient
from test_service import AUTH, TOKEN, FakeSampler, _campaign, _settings

from daemon.api.main import create_app

CSV = {**AUTH, "Content-Type": "text/csv"}
JSON = {"Content-Type": "application/json"}
MB = 1024 * 1024


@pytest.fixture(scope="module")
def client(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TestClient]:
    app = create_app(
        _settings(tmp_path_factory.mktemp("bounds")), TOKEN, sampler_factory=FakeSampler
    )
    with TestClient(app, raise_server_exceptions=False) as c:
        yield c


class CountingBody:
    """A request body of ``total`` bytes streamed in ``chunk`` byte pieces (no
    Content-Length: chunked), counting how many pieces the app pulled."""

    def __init__(self, total: int, chunk: int = 64 * 1024, fill: bytes = b"x") -> None:
        self.total, self.chunk, self.fill = total, chunk, fill
        self.pulled = 0

    async def receive(self) -> dict[str, Any]:
        sent = self.pulled * self.chunk
        if sent >= self.total:
            return {"type": "http.disconnect"}
        self.pulled += 1
        n = min(self.chunk, self.total - sent)
        return {"type": "http.request", "body": self.fill * n, "more_body": sent + n < self.total}


def _asgi_post(client: TestClient, path: str, body: CountingBody, headers: dict[str, str]) -> int:
    """POST ``body`` straight to the running app (TestClient would read it all first); the
    response status."""
    scope = {
        "type": "http",
        "asgi": {"version": "3.0"},
        "http_version": "1.1",
        "method": "POST",
        "path": path,
        "raw_path": path.encode(),
        "root_path": "",
        "scheme": "http",
        "query_string": b"",
        "client": ("testclient", 1),
        "server": ("testserver", 80),
        "headers": [(k.lower().encode(), v.encode()) for k, v in headers.items()],
    }
    started: list[int] = []

    async def send(message: Any) -> None:
        if message["type"] == "http.response.start":
            started.append(int(message["status"]))

    async def call() -> None:
        await client.app(scope, body.receive, send)

    assert client.portal is not None
    client.portal.call(call)
    return started[0]


# ----------------------------------------------------------------------- auth before body
def test_no_token_is_401_before_the_body_is_read(client: TestClient) -> None:
    # Malformed JSON without a token: 401, not 422.
    r = client.post("/api/v1/campaigns", content=b"{not json", headers=JSON)
    assert r.status_code == 401 and r.headers["www-authenticate"] == "Bearer", r.text
    # A 100 MB body without a token (or with a wrong one): refused before any of it is read.
    for headers in (JSON, {**JSON, "Authorization": "Bearer wrong-token-0123456789"}):
        body = CountingBody(100 * MB)
        assert _asgi_post(client, "/api/v1/campaigns", body, headers) == 401
        assert body.pulled == 0
    body = CountingBody(100 * MB)
    assert _asgi_post(client, "/api/v1/campaigns/1/samples/import", body, {}) == 401
    assert body.pulled == 0


# ----------------------------------------------------------------------- body limits
def test_json_body_over_the_limit_is_413_while_streaming(client: TestClient) -> None:
    from daemon.api.http.guard import MAX_JSON_BYTES

    body = CountingBody(50 * MB)
    assert _asgi_post(client, "/api/v1/campaigns", body, {**AUTH, **JSON}) == 413
    assert body.pulled * body.chunk <= MAX_JSON_BYTES + body.chunk, body.pulled
    # A declared Content-Length over the limit: refused at once.
    r = client.post("/api/v1/campaigns", content=b"x" * (MAX_JSON_BYTES + 1), headers=AUTH)
    assert r.status_code == 413 and str(MAX_JSON_BYTES) in r.json()["detail"], r.text


def test_import_over_20_mib_is_413_before_it_is_all_in_memory(client: TestClient) -> None:
    from daemon.api.http.guard import MAX_IMPORT_BYTES

    cid = _campaign(client, "big-import")
    body = CountingBody(200 * MB, chunk=MB, fill=b"0,")
    status = _asgi_post(client, f"/api/v1/campaigns/{cid}/samples/import", body, CSV)
    assert status == 413
    assert body.pulled * body.chunk <= MAX_IMPORT_BYTES + body.chunk, body.pulled
    assert client.get(f"/api/v1/campaigns/{cid}", headers=AUTH).json()["n_samples"] == 0
    r = client.post(
        f"/api/v1/campaigns/{cid}/samples/import",
        content=b"0" * (MAX_IMPORT_BYTES + 1),
        headers=CSV,
    )
    assert r.status_code == 413


def test_notes_and_names_have_length_limits(client: TestClient) -> None:
    from daemon.api.text_rules import MAX_NAME_CHARS, MAX_NOTES_CHARS

    r = client.post("/api/v1/campaigns", json={"name": "n", "notes": "x" * 200_000}, headers=AUTH)
    assert r.status_code == 422 and r.json()["detail"][0]["loc"] == ["body", "notes"], r.text
    assert len(r.content) < 2000  # the error does not echo the input
    r = client.post("/api/v1/campaigns", json={"name": "n" * (MAX_NAME_CHARS + 1)}, headers=AUTH)
    assert r.status_code == 422 and "name" in r.text
    r = client.post(
        "/api/v1/campaigns", json={"name": "ok", "notes": "y" * MAX_NOTES_CHARS}, headers=AUTH
    )
    assert r.status_code == 201


# ----------------------------------------------------------------------- pagination
def _next_link(r: Any) -> str | None:
    link = r.headers.get("link")
    if link is None:
        return None
    assert link.endswith('>; rel="next"'), link
    return str(link[1 : link.index(">")])


def test_campaigns_samples_jobs_and_events_are_paginated(client: TestClient) -> None:
    ids = [_campaign(client, f"page-{k}") for k in range(5)]
    seen: list[int] = []
    url: str | None = f"/api/v1/campaigns?limit=2&after_id={ids[0] - 1}"
    while url is not None:
        r = client.get(url, headers=AUTH)
        assert r.status_code == 200 and len(r.json()) <= 2
        seen += [c["id"] for c in r.json()]
        url = _next_link(r)
    assert seen == sorted(seen) and set(ids) <= set(seen)
    assert client.get("/api/v1/campaigns?limit=10001", headers=AUTH).status_code == 422
    assert client.get("/api/v1/campaigns?limit=0", headers=AUTH).status_code == 422
    # Samples: the default page is the first 1000 rows, with a next link.
    cid = ids[0]
    rows = "\n".join(["q1,q2,q3,q4,q5,q6,L", *(["0,0,200,0,0,0,500"] * 1203)]) + "\n"
    r = client.post(f"/api/v1/campaigns/{cid}/samples/import", content=rows, headers=CSV)
    assert r.status_code == 201, r.text
    first = client.get(f"/api/v1/campaigns/{cid}/samples", headers=AUTH)
    assert len(first.json()) == 1000 and first.json()[0]["id"] == r.json()["sample_ids"][0]
    nxt = _next_link(first)
    assert nxt is not None and "after_id=" in nxt
    rest = client.get(nxt, headers=AUTH)
    assert len(rest.json()) == 203 and _next_link(rest) is None
    got = [s["id"] for s in first.json() + rest.json()]
    assert got == r.json()["sample_ids"]
    assert client.get(f"/api/v1/campaigns/{cid}/identifications?limit=5", headers=AUTH).json() == []
    events = client.get("/api/v1/events?since_id=0&limit=1", headers=AUTH)
    assert len(events.json()) == 1 and "since_id=" in (_next_link(events) or "")


# ----------------------------------------------------------------------- error contract
def test_every_4xx_has_the_one_error_shape(client: TestClient) -> None:
    cid = _campaign(client, "shape")
    cases_422 = [
        ("POST", "/api/v1/campaigns", {"name": "u", "robot_model": "nope"}),
        ("POST", "/api/v1/campaigns", {"name": "x", "robot_model": {"name": "m"}}),
    ]
    for method, url, body in cases_422:
        r = client.request(method, url, json=body, headers=AUTH)
        assert r.status_code == 422, (url, r.text)
        detail = r.json()["detail"]
        assert isinstance(detail, list) and detail, (url, r.text)
        for issue in detail:
            assert set(issue) == {"loc", "msg", "type"} and issue["loc"][0] == "body", r.text
    for r in (
        # the campaign's state refuses (issue 21: 409, the schema allows the request)
        client.post(f"/api/v1/campaigns/{cid}/identifications", json={}, headers=AUTH),
        client.post(
            f"/api/v1/campaigns/{cid}/captures",
            json={"joints_deg": [0, 500, 200, 0, 0, 0]},
            headers=AUTH,
        ),
        client.get("/api/v1/campaigns/999999", headers=AUTH),
        client.get("/api/v1/campaigns"),
        client.post("/api/v1/campaigns", content=b"x" * (MB + 1), headers=AUTH),
    ):
        assert r.status_code in (401, 404, 409, 413), r.text
        assert isinstance(r.json()["detail"], str), r.text


def test_openapi_declares_every_error_status(client: TestClient) -> None:
    paths = client.get("/openapi.json").json()["paths"]
    for path, ops in paths.items():
        if not path.startswith("/api/v1") or path == "/api/v1/health":
            continue
        for method, op in ops.items():
            codes = set(op["responses"])
            assert {"401", "413", "422"} <= codes, (method, path, codes)
            if "{" in path:
                assert "404" in codes, (method, path, codes)
            for code in codes - {"200", "201", "202"}:
                schema = op["responses"][code]["content"]["application/json"]["schema"]
                assert schema["$ref"].rsplit("/", 1)[1] in ("Error", "ValidationErrors")
    assert "400" in paths["/api/v1/campaigns/{campaign_id}/samples/import"]["post"]["responses"]


# ----------------------------------------------------------------------- the event loop
@pytest.mark.timeout(300)
def test_a_500k_row_import_does_not_stall_health_or_the_loop(client: TestClient) -> None:
    """/health latency and event-loop lag (a 10 ms ticker on the app's loop, standing in for
    the sampler's poll loop) while a 500 000-row import runs, against a baseline measured
    just before in the same run. Before the fix the import ran on the loop: 10+ s stalls."""
    n_rows = 500_000
    cid = _campaign(client, "huge")
    text = "q1,q2,q3,q4,q5,q6,L\n" + "0,0,200,0,0,0,500\n" * n_rows
    portal = client.portal
    assert portal is not None
    lags: list[float] = []
    stop = threading.Event()

    async def ticker() -> None:
        while not stop.is_set():
            t0 = time.perf_counter()
            await asyncio.sleep(0.01)
            lags.append(time.perf_counter() - t0 - 0.01)

    def health_latencies(until: threading.Event | None, count: int) -> list[float]:
        out = []
        while (until is None and len(out) < count) or (until is not None and not until.is_set()):
            t0 = time.perf_counter()
            assert client.get("/api/v1/health").status_code == 200
            out.append(time.perf_counter() - t0)
            time.sleep(0.02)
        return out

    tick = portal.start_task_soon(ticker)
    baseline = health_latencies(None, 30)
    base_lag = max(lags)
    lags.clear()
    done = threading.Event()
    result: dict[str, Any] = {}

    def run_import() -> None:
        t0 = time.perf_counter()
        r = client.post(f"/api/v1/campaigns/{cid}/samples/import", content=text, headers=CSV)
        result.update(status=r.status_code, n=r.json().get("imported"), s=time.perf_counter() - t0)
        done.set()

    worker = threading.Thread(target=run_import)
    worker.start()
    during = health_latencies(done, 0)
    worker.join(timeout=300)
    stop.set()
    tick.result(timeout=5)
    assert result["status"] == 201 and result["n"] == n_rows, result
    delay_s = max(during) - statistics.median(baseline)
    print(
        f"\n500k-row import {result['s']:.1f} s; /health baseline median "
        f"{statistics.median(baseline) * 1e3:.1f} ms max {max(baseline) * 1e3:.1f} ms; during: "
        f"{len(during)} requests, median {statistics.median(during) * 1e3:.1f} ms, max "
        f"{max(during) * 1e3:.1f} ms; loop lag baseline max {base_lag * 1e3:.1f} ms, "
        f"during max {max(lags) * 1e3:.1f} ms"
    )
    assert len(during) >= 5
    # On a loaded machine a thread may wait 100+ ms for a core now and then, import or not:
    # the 95th percentile carries the 100 ms bound, the maximum a looser one (before the fix,
    # both were the whole import: 10+ s).
    p95 = statistics.quantiles(during, n=20)[-1]
    assert p95 - statistics.median(baseline) < 0.1, f"/health p95 {p95 * 1e3:.0f} ms"
    assert delay_s < 0.5, f"/health delayed {delay_s * 1e3:.0f} ms during the import"
    assert max(lags) < 0.5 + base_lag, f"event loop lag {max(lags) * 1e3:.0f} ms"
