"""Issue 31, sixth pass: the per-peer request rate (token bucket, 429 with Retry-After, the
refusal delayed), campaigns and imports a minute, a loop of writes stopping at the disk
reserve with nothing lost, and the CSV export streamed page by page from the store."""

from __future__ import annotations

import asyncio
import multiprocessing
import sqlite3
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi import HTTPException
from fastapi.testclient import TestClient
from test_service import AUTH, TOKEN, FakeSampler

from calib.dataset import make_samples, samples_to_csv
from daemon.api.http.guard import BYTES_PER_TOKEN, TokenBuckets, peer_key, request_cost
from daemon.api.http.offload import WorkGate, offload
from daemon.api.main import create_app
from daemon.config import Settings
from daemon.process.workers import run_in_child
from daemon.sampler.capture import Capture
from daemon.store import Store, space

API = "/api/v1"
#: A network peer for the TestClient (TEST-NET-1): the limits count network peers only.
PEER = ("192.0.2.7", 40000)
OTHER_PEER = ("192.0.2.8", 40000)
ROBOT = "hsr-jr680"
CSV_HEADER = "q1,q2,q3,q4,q5,q6,L,anchor"


def _csv(n: int, seed: int) -> str:
    """``n`` valid sample rows (inside the hsr-jr680's limits) as CSV text."""
    rng = np.random.default_rng(seed)
    q = rng.uniform(-30.0, 30.0, (n, 6)) + np.array([0.0, -30.0, 150.0, 0.0, 0.0, 0.0])
    return samples_to_csv(make_samples(q, 500.0 + 100.0 * rng.random(n)))


# --- the token bucket -------------------------------------------------------------------------


def test_token_buckets_grant_a_burst_then_the_rate_and_say_how_long_to_wait() -> None:
    now = [100.0]
    buckets = TokenBuckets(rate_per_s=2.0, burst=3, clock=lambda: now[0])
    assert [buckets.take("a") for _ in range(3)] == [0.0, 0.0, 0.0]
    assert buckets.take("a") == pytest.approx(0.5)  # one token comes in 1/2 s
    assert buckets.take("b") == 0.0  # another key has its own bucket
    now[0] += 0.5
    assert buckets.take("a") == 0.0
    assert buckets.take("a") == pytest.approx(0.5)
    now[0] += 100.0  # full again, never more than the burst
    assert [buckets.take("a") for _ in range(4)][-1] > 0.0
    assert TokenBuckets(0.0, 1).take("a") == 0.0  # rate 0: no limit


def test_a_request_with_a_body_costs_more_tokens_and_at_most_the_burst() -> None:
    now = [0.0]
    buckets = TokenBuckets(rate_per_s=4.0, burst=10, clock=lambda: now[0])
    assert buckets.take("a", 6.0) == 0.0
    assert buckets.take("a", 6.0) == pytest.approx(0.5)  # 4 left, 2 more in 1/2 s
    now[0] += 10.0
    assert buckets.take("a", 1000.0) == 0.0  # a cost over the burst takes the burst
    assert buckets.take("a") == pytest.approx(0.25)

    def scope(*headers: tuple[bytes, bytes]) -> dict[str, Any]:
        return {"headers": list(headers)}

    assert request_cost(scope(), "/api/v1/campaigns") == 1.0
    cost = request_cost(scope((b"content-length", str(300 * 1024).encode())), "/x")
    assert cost == pytest.approx(1.0 + 300 * 1024 / BYTES_PER_TOKEN)
    chunked = scope((b"transfer-encoding", b"chunked"))
    assert request_cost(chunked, "/api/v1/robots/1/filter") == 1.0 + 16 * 1024**2 / BYTES_PER_TOKEN


def test_token_buckets_forget_idle_keys_beyond_their_bound() -> None:
    now = [0.0]
    buckets = TokenBuckets(rate_per_s=10.0, burst=2, clock=lambda: now[0])
    buckets.max_keys = 8
    for k in range(100):
        now[0] += 1.0  # each key idle long enough to be full again
        assert buckets.take(k) == 0.0
    assert len(buckets._buckets) <= 8
    for k in range(100, 200):  # none idle: the oldest half goes
        assert buckets.take(k) == 0.0
    assert len(buckets._buckets) <= 8


def test_the_rate_key_is_the_peers_ip_address() -> None:
    assert peer_key({"client": ("192.0.2.7", 1)}) == "192.0.2.7"
    assert peer_key({"client": ("::1", 1)}) == "::1"
    assert peer_key({"client": ("testclient", 1)}) is None  # in-process: not counted
    assert peer_key({"client": None}) is None


# --- through the API --------------------------------------------------------------------------


@pytest.fixture
def limited(tmp_path: Path) -> Iterator[TestClient]:
    """An app with a small rate, campaigns and imports a minute; its client is a network
    peer."""
    settings = Settings(
        state_dir=tmp_path,
        api_token=TOKEN,
        requests={
            "rate_per_s": 0.01,
            "rate_burst": 4,
            "rate_refusal_delay_s": 0.2,
            "campaigns_per_min": 2,
            "imports_per_min": 1,
        },
    )
    app = create_app(settings, TOKEN, sampler_factory=FakeSampler)
    with TestClient(app, client=PEER) as c:
        yield c


def test_a_peer_over_its_rate_gets_a_late_429_with_retry_after(limited: TestClient) -> None:
    for _ in range(4):
        assert limited.get(f"{API}/campaigns", headers=AUTH).status_code == 200
    t0 = time.monotonic()
    r = limited.get(f"{API}/campaigns", headers=AUTH)
    assert time.monotonic() - t0 >= 0.19  # answered after rate_refusal_delay_s (0.2 s)
    assert r.status_code == 429, r.text
    assert int(r.headers["retry-after"]) >= 1
    assert r.headers["connection"] == "close"
    detail = r.json()["detail"]
    assert "192.0.2.7" in detail and "rate_per_s" in detail and "rate_burst" in detail
    # Without the token too (the rate comes first), and /health is not counted.
    assert limited.post(f"{API}/campaigns", json={}).status_code == 429
    for _ in range(10):
        assert limited.get(f"{API}/health").status_code == 200
        assert limited.get("/metrics").status_code == 200  # not the REST API: not counted
    # Another peer has its own bucket; an in-process client is not counted.
    app = limited.app
    assert TestClient(app, client=OTHER_PEER).get(f"{API}/campaigns", headers=AUTH).is_success
    assert TestClient(app).get(f"{API}/campaigns", headers=AUTH).is_success


def test_campaigns_and_imports_a_minute_are_limited_with_a_named_429(tmp_path: Path) -> None:
    settings = Settings(
        state_dir=tmp_path,
        api_token=TOKEN,
        requests={"campaigns_per_min": 2, "imports_per_min": 1},
    )
    app = create_app(settings, TOKEN, sampler_factory=FakeSampler)
    with TestClient(app, client=PEER) as c:
        body = {"name": "c", "robot_model": ROBOT}
        ids = [c.post(f"{API}/campaigns", json=body, headers=AUTH).json()["id"] for _ in range(2)]
        r = c.post(f"{API}/campaigns", json=body, headers=AUTH)
        assert r.status_code == 429, r.text
        assert "campaigns_per_min" in r.json()["detail"] and int(r.headers["retry-after"]) >= 1
        assert len(c.get(f"{API}/campaigns", headers=AUTH).json()) == 2  # nothing created
        csv_headers = {**AUTH, "Content-Type": "text/csv"}
        url = f"{API}/campaigns/{ids[0]}/samples/import"
        assert c.post(url, content=_csv(5, 1), headers=csv_headers).status_code == 201
        r = c.post(url, content=_csv(5, 2), headers=csv_headers)
        assert r.status_code == 429 and "imports_per_min" in r.json()["detail"], r.text
        assert c.get(f"{API}/campaigns/{ids[0]}", headers=AUTH).json()["n_included"] == 5
        # In-process callers (no network peer) are not counted.
        assert TestClient(app).post(f"{API}/campaigns", json=body, headers=AUTH).status_code == 201


def test_a_loop_of_campaigns_and_imports_stops_at_the_reserve_with_nothing_lost(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A file system of 24 MiB whose free space is what the state directory does not use,
    a reserve of 12 MiB: creating a campaign and importing 2,000 rows into it, again and
    again, ends with a 507; every write answered 201 is there, whole, and the refused one left
    nothing."""
    capacity = 24 * space.MIB

    def free(path: Path) -> int:
        used = sum(f.stat().st_size for f in tmp_path.rglob("*") if f.is_file())
        return capacity - used

    monkeypatch.setattr(space, "free_bytes", free)
    settings = Settings(state_dir=tmp_path, api_token=TOKEN, requests={"disk_reserve_mb": 12})
    app = create_app(settings, TOKEN, sampler_factory=FakeSampler)
    imported: dict[int, int] = {}
    refused: dict[str, Any] | None = None
    with TestClient(app) as c:
        for k in range(200):
            r = c.post(
                f"{API}/campaigns", json={"name": f"c{k}", "robot_model": ROBOT}, headers=AUTH
            )
            if r.status_code == 507:
                refused = {"what": "campaign", "detail": r.json()["detail"]}
                break
            assert r.status_code == 201, r.text
            cid = int(r.json()["id"])
            imported[cid] = 0
            r = c.post(
                f"{API}/campaigns/{cid}/samples/import",
                content=_csv(2000, k),
                headers={**AUTH, "Content-Type": "text/csv"},
            )
            if r.status_code == 507:
                refused = {"what": "import", "detail": r.json()["detail"]}
                break
            assert r.status_code == 201, r.text
            imported[cid] = 2000
        assert refused is not None, "the loop never reached the reserve"
        assert "disk_reserve_mb" in refused["detail"] and "nothing written" in refused["detail"]
        assert len(imported) >= 2  # it wrote before it stopped
        listed = {row["id"]: row["n_included"] for row in _all_campaigns(c)}
        assert listed == imported  # nothing lost, nothing of the refused write
    with sqlite3.connect(settings.database_path) as db:
        assert db.execute("PRAGMA integrity_check").fetchone() == ("ok",)


def _all_campaigns(c: TestClient) -> list[dict[str, Any]]:
    rows: list[dict[str, Any]] = []
    after = 0
    while page := c.get(f"{API}/campaigns?after_id={after}&limit=100", headers=AUTH).json():
        rows += page
        after = page[-1]["id"]
    return rows


# --- the streamed CSV export ------------------------------------------------------------------


def _capture(k: int, t_end: float, anchor: str = "A") -> Capture:
    q = (float(k % 7), -30.0 + k % 5, 150.0, 0.5 * k % 3, 1.0, 2.0)
    return Capture(q, (0.0,) * 6, 500.0 + k, 0.0, 3, anchor, t_end - 0.2, t_end, "manual")  # type: ignore[arg-type]


@pytest.mark.parametrize("case", ["empty", "imported", "captured", "grouped", "time goes back"])
def test_the_streamed_export_is_the_whole_export_in_pages(tmp_path: Path, case: str) -> None:
    store = Store(tmp_path / "s.sqlite3")
    try:
        robot = store.ensure_builtin_robot(ROBOT)
        cid = int(store.create_campaign("c", robot["id"])["id"])
        rows = 0
        if case in ("imported", "grouped"):
            rng = np.random.default_rng(3)
            q = rng.uniform(-30.0, 30.0, (23, 6)) + np.array([0, -30.0, 150.0, 0, 0, 0])
            groups = [f"g{k // 4}" if k % 3 else "" for k in range(23)]
            group = groups if case == "grouped" else None
            store.import_samples(cid, make_samples(q, 500.0 + rng.random(23), group=group))
            rows = 23
        elif case in ("captured", "time goes back"):
            stamps = 1_700_000_000.0 + 1.5 * np.arange(23)
            if case == "time goes back":
                stamps[11] -= 100.0
            for k, t in enumerate(stamps):
                store.store_capture(cid, _capture(k, float(t), "AB"[k % 2]))
            store.set_excluded(int(store.list_samples(cid)[4]["id"]), True, "test")
            rows = 22
        whole = store.export_csv(cid)
        for page_rows in (1, 5, 22, 23, 5000):
            assert "".join(store.export_csv_pages(cid, page_rows)) == whole
        header, *lines = whole.splitlines()
        assert len(lines) == rows
        assert header.split(",")[:8] == CSV_HEADER.split(",")
        assert header.endswith(",t_s") == (case == "captured")
        assert (",group" in header) == (case == "grouped")
    finally:
        store.close()


def test_the_csv_route_streams_the_same_text(tmp_path: Path) -> None:
    settings = Settings(state_dir=tmp_path, api_token=TOKEN)
    with TestClient(create_app(settings, TOKEN, sampler_factory=FakeSampler)) as c:
        cid = c.post(f"{API}/campaigns", json={"name": "c", "robot_model": ROBOT}, headers=AUTH)
        cid_n = int(cid.json()["id"])
        r = c.post(
            f"{API}/campaigns/{cid_n}/samples/import",
            content=_csv(12_000, 4),  # more than two pages
            headers={**AUTH, "Content-Type": "text/csv"},
        )
        assert r.status_code == 201, r.text
        r = c.get(f"{API}/campaigns/{cid_n}/samples?format=csv", headers=AUTH)
        assert r.status_code == 200 and r.headers["content-type"].startswith("text/csv")
        store = c.app.state.cablecal.store  # type: ignore[attr-defined]
        assert r.text == store.export_csv(cid_n)
        assert len(r.text.splitlines()) == 12_001
        gate = c.app.state.cablecal.gates["check"]  # type: ignore[attr-defined]
        assert gate.active == 0  # every page's place given back
        assert c.get(f"{API}/campaigns/999/samples?format=csv", headers=AUTH).status_code == 404


# --- the gate's queue wait --------------------------------------------------------------------


def test_work_waiting_longer_than_the_queue_timeout_is_a_503_with_retry_after() -> None:
    async def scenario() -> tuple[int, str, str | None]:
        gate = WorkGate("program filters", 1, 1, retry_after_s=7, queue_timeout_s=0.05)
        held = asyncio.Event()
        release = asyncio.Event()

        async def hold() -> None:
            async with gate.slot():
                held.set()
                await release.wait()

        holder = asyncio.create_task(hold())
        await held.wait()
        try:
            async with gate.slot():
                raise AssertionError("the place was held")
        except HTTPException as exc:
            caught = exc
        finally:
            release.set()
            await holder
        assert gate._waiting == 0 and gate.active == 0
        async with gate.slot():  # free again
            pass
        headers = caught.headers or {}
        return caught.status_code, str(caught.detail), headers.get("Retry-After")

    status, detail, retry = asyncio.run(scenario())
    assert status == 503 and retry == "7"
    assert "queue_timeout_s" in detail and "program filters" in detail


class _StayingClient:
    """A request whose client stays connected."""

    async def receive(self) -> dict[str, Any]:
        await asyncio.Event().wait()
        raise AssertionError("unreachable")


def test_work_over_its_time_limit_is_a_503_and_its_process_is_killed() -> None:
    async def scenario() -> tuple[HTTPException, int | None]:
        gate = WorkGate("program filters", 1, 0, retry_after_s=4)
        task = asyncio.create_task(
            offload(
                _StayingClient(),  # type: ignore[arg-type]
                gate,
                lambda: run_in_child(_sleep_then_answer, 60.0),
                time_limit_s=1.0,
            )
        )
        deadline = time.monotonic() + 60
        while not multiprocessing.active_children():  # the child is up before the limit counts
            assert time.monotonic() < deadline
            await asyncio.sleep(0.02)
        (child,) = multiprocessing.active_children()
        with pytest.raises(HTTPException) as info:
            await task
        assert gate.active == 0  # its place given back
        return info.value, child.exitcode

    refused, exitcode = asyncio.run(scenario())
    assert refused.status_code == 503 and (refused.headers or {})["Retry-After"] == "4"
    assert "filter_timeout_s" in str(refused.detail)
    assert exitcode == -9  # killed, not left to sleep its minute
    assert not multiprocessing.active_children()


def _sleep_then_answer(seconds: float) -> str:
    time.sleep(seconds)
    return "done"
