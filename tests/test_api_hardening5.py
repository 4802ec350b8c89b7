"""Issue 31, scaled down to run in seconds: the streaming multipart reader and its limits,
the bounded heavy work (filters in worker processes killed on cancel, 429 with Retry-After),
the pending-job cap, the free-space guard (507, nothing written), capped list pages, the
printable-text and portable-name rules, ASCII logs, a cancel at shutdown answered 503, the
head limit counting whitespace, slow readers dropped, readiness with the POST's hold-out."""

# ruff: noqa: F811  (the fixtures of test_api_apply are imported, then named as arguments)

from __future__ import annotations

import asyncio
import io
import logging
import multiprocessing
import socket
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.exceptions import RequestValidationError
from fastapi.testclient import TestClient
from helpers import closed_by_server, served_app
from starlette.exceptions import HTTPException
from test_api_apply import calibrated, cell  # noqa: F401
from test_service import AUTH, TOKEN, FakeSampler

from daemon.api.http.multipart import MAX_PART_HEADER_BYTES, FormReader
from daemon.api.http.offload import CancelledIs503, WorkGate, offload
from daemon.api.http.server import MAX_HEAD_BYTES, uvicorn_options
from daemon.api.main import create_app
from daemon.api.text_rules import not_portable_file_name, not_printable
from daemon.config import Settings
from daemon.process.logs import setup_logging
from daemon.process.workers import run_in_child

API = "/api/v1"
B = b"Bnd7"
CT = "multipart/form-data; boundary=Bnd7"
FIELDS = {"files": 50, "frames": 1}
PROGRAM = b"MODULE M\nENDMODULE\n"


def _part(disposition: bytes, data: bytes = PROGRAM) -> bytes:
    return b"--" + B + b"\r\nContent-Disposition: " + disposition + b"\r\n\r\n" + data + b"\r\n"


def _body(*parts: bytes, close: bool = True) -> bytes:
    return b"".join(parts) + (b"--" + B + b"--\r\n" if close else b"")


def _read(raw: bytes, chunk: int = 4096) -> list[Any]:
    reader = FormReader(CT, FIELDS, 1 << 20)
    for k in range(0, len(raw), chunk):
        reader.feed(raw[k : k + chunk])
    return reader.finish()


def _refusal(raw: bytes) -> str:
    with pytest.raises((RequestValidationError, HTTPException)) as info:
        _read(raw)
    exc = info.value
    if isinstance(exc, RequestValidationError):
        return " ".join(str(e["msg"]) for e in exc.errors())
    return str(exc.detail)


# --- the multipart reader -----------------------------------------------------------------


def test_a_well_formed_body_is_read_in_any_chunking() -> None:
    raw = _body(
        _part(b'form-data; name="files"; filename="a.mod"'),
        _part(b'form-data; name="frames"; filename="f.toml"', b"[x]\r\n--Bnd"),
    )
    for chunk in (1, 7, 4096):
        parts = _read(raw, chunk)
        assert [(p.name, p.filename, bytes(p.data)) for p in parts] == [
            ("files", "a.mod", PROGRAM),
            ("frames", "f.toml", b"[x]\r\n--Bnd"),
        ]


def test_hostile_bodies_are_refused_while_reading_within_milliseconds() -> None:
    """The attacks of the issue, each at its size there (300 KiB and up): refused at the
    first part or header over a limit, never parsed to the end."""
    rfc2231 = b"".join(b"; filename*%d=x" % k for k in range(16_000))  # 302 KiB in the issue
    plain = b"".join(b"; p%d=1" % k for k in range(64_000))
    tiny = b"".join(
        _part(b'form-data; name="files"; filename="f%d.mod"' % k, b"x") for k in range(10_000)
    )
    nested = b'form-data; name="files"; filename="a.mod"' + b"(" * 500 + b")" * 500
    cases = {
        "Maximum header size": _body(_part(b'form-data; name="files"' + rfc2231)),
        "Maximum header size exceeded": _body(_part(b'form-data; name="files"' + plain)),
        "headers longer than": _body(
            b"--"
            + B
            + b"\r\n"
            + b"".join(b"X-%d: %s\r\n" % (k, b"v" * 400) for k in range(6))
            + b"\r\nx\r\n"
        ),
        "Maximum header count": _body(
            b"--" + B + b"\r\n" + b"".join(b"X-%d: v\r\n" % k for k in range(9)) + b"\r\nx\r\n"
        ),
        "at most 50 parts": _body(tiny),
        "no Content-Disposition": _body(b"--" + B + b"\r\nX-A: 1\r\n\r\nx\r\n"),
        "its Content-Disposition has no name": _body(_part(b"form-data")),
        "unknown part 'other'": _body(_part(b'form-data; name="other"')),
        "truncated": _body(_part(b'form-data; name="files"; filename="a.mod"'), close=False),
        "over 8 parameters": _body(_part(b"form-data" + b"; a=1" * 9)),
        "Content-Transfer-Encoding": _body(
            b"--" + B + b'\r\nContent-Disposition: form-data; name="files"\r\n'
            b"Content-Transfer-Encoding: base64\r\n\r\nTUFJTg==\r\n"
        ),
    }
    for expected, raw in cases.items():
        t0 = time.perf_counter()
        message = _refusal(raw)
        assert expected in message, (expected, message)
        assert time.perf_counter() - t0 < 0.5, expected
    # Nested parentheses are plain characters here: no recursion, the body is read.
    assert len(_read(_body(_part(nested)))) == 1
    assert 2 * len(rfc2231) > MAX_PART_HEADER_BYTES


def test_data_over_the_limit_is_a_413_while_reading() -> None:
    reader = FormReader(CT, FIELDS, 1000)
    reader.feed(b"--" + B + b'\r\nContent-Disposition: form-data; name="files"\r\n\r\n')
    with pytest.raises(HTTPException) as info:
        for _ in range(10):
            reader.feed(b"x" * 200)
    assert info.value.status_code == 413


def test_a_content_type_without_a_boundary_is_refused() -> None:
    for ct in ("multipart/form-data", "text/plain; boundary=x", "multipart/form-data; " * 50):
        with pytest.raises(RequestValidationError):
            FormReader(ct, FIELDS, 1000)


# --- names and text -----------------------------------------------------------------------


@pytest.mark.parametrize(
    ("name", "taken", "why"),
    [
        ("A.mod", ["a.mod"], "only in case"),
        ("a.mod", ["a.mod"], "given twice"),
        ("C:evil.mod", [], "must be a plain name"),
        ("CON.mod", [], "reserved device name"),
        ("lpt9", [], "reserved device name"),
        ("x\x7f.mod", [], "must be a plain name"),
        ("x\u0085.mod", [], "must be a plain name"),
        ("x\u202e.mod", [], "must be a plain name"),
        ("x\u2028.mod", [], "must be a plain name"),
        ("trailing.", [], "must be a plain name"),
    ],
)
def test_file_names_are_portable(name: str, taken: list[str], why: str) -> None:
    assert why in (not_portable_file_name(name, taken) or "")


def test_portable_names_pass() -> None:
    for name in ("cell_a.mod", "MAIN.LS", "Prog 2 (copy).script", "_x-1+2.src", "CONSOLE.mod"):
        assert not_portable_file_name(name) is None, name


def test_format_characters_and_separators_are_not_printable() -> None:
    for char in ("\u202e", "\u2066", "\u200b", "\ufeff", "\ufffe", "\u2028", "\u2029"):
        assert not_printable(f"ab{char}c") is not None, hex(ord(char))
    assert not_printable("Grüße, 日本 — ok") is None


def test_logs_are_ascii() -> None:
    for json_lines in (True, False):
        out = io.StringIO()
        setup_logging("INFO", json_lines, stream=out)
        try:
            logging.getLogger("cablecal.test").warning("name a\u202eb\u2028c é")
        finally:
            setup_logging("INFO", json_lines, stream=io.StringIO())
        text = out.getvalue()
        assert text.isascii() and "\\u202e" in text and text.count("\n") == 1, text


# --- bounded work ---------------------------------------------------------------------------


def test_a_full_gate_is_a_429_with_retry_after_and_a_closed_one_a_503() -> None:
    async def scenario() -> None:
        gate = WorkGate("filters", running=1, queued=1, retry_after_s=7)
        release = asyncio.Event()
        order: list[str] = []

        async def hold(tag: str) -> None:
            async with gate.slot():
                order.append(tag)
                await release.wait()

        first = asyncio.create_task(hold("first"))
        await asyncio.sleep(0)
        second = asyncio.create_task(hold("second"))  # waits in the queue
        await asyncio.sleep(0)
        with pytest.raises(HTTPException) as info:
            async with gate.slot():
                pass
        assert info.value.status_code == 429
        assert info.value.headers == {"Retry-After": "7"}
        release.set()
        await asyncio.gather(first, second)
        assert order == ["first", "second"]
        gate.close()
        with pytest.raises(HTTPException) as info:
            async with gate.slot():
                pass
        assert info.value.status_code == 503

    asyncio.run(scenario())


def _sleep_then_answer(seconds: float) -> str:
    time.sleep(seconds)
    return "done"


def test_work_in_a_child_returns_and_a_cancel_kills_the_process() -> None:
    async def scenario() -> None:
        assert await run_in_child(_sleep_then_answer, 0.0) == "done"
        task = asyncio.create_task(run_in_child(_sleep_then_answer, 60.0))
        deadline = time.monotonic() + 30
        while not multiprocessing.active_children():
            assert time.monotonic() < deadline
            await asyncio.sleep(0.02)
        (child,) = multiprocessing.active_children()
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task
        assert child.exitcode == -9  # killed, not left to sleep its minute
        assert not multiprocessing.active_children()

    asyncio.run(scenario())


class _LeavingClient:
    """A request whose client disconnects when :attr:`gone` is set."""

    def __init__(self) -> None:
        self.gone = asyncio.Event()

    async def receive(self) -> dict[str, Any]:
        await self.gone.wait()
        return {"type": "http.disconnect"}


def test_work_is_cancelled_when_its_client_leaves_and_the_place_freed() -> None:
    async def scenario() -> None:
        gate = WorkGate("filters", running=1, queued=0, retry_after_s=1)
        request = _LeavingClient()
        started, cancelled = asyncio.Event(), asyncio.Event()

        async def work() -> None:
            started.set()
            try:
                await asyncio.Event().wait()
            except asyncio.CancelledError:
                cancelled.set()
                raise

        call = asyncio.create_task(offload(request, gate, work))  # type: ignore[arg-type]
        await started.wait()
        assert gate.active == 1
        request.gone.set()
        with pytest.raises(HTTPException) as info:
            await call
        assert info.value.status_code == 503 and "client disconnected" in str(info.value.detail)
        assert cancelled.is_set() and gate.active == 0

    asyncio.run(scenario())


def test_an_exception_of_the_child_is_raised_in_the_daemon() -> None:
    with pytest.raises(ValueError, match="invalid literal"):
        asyncio.run(run_in_child(int, "x"))


def test_a_request_cancelled_before_its_response_is_a_503() -> None:
    sent: list[dict[str, Any]] = []

    async def never(scope: Any, receive: Any, send: Any) -> None:
        await asyncio.Event().wait()

    async def send(message: dict[str, Any]) -> None:
        sent.append(message)

    async def scenario() -> None:
        app = CancelledIs503(never)
        task = asyncio.create_task(app({"type": "http"}, None, send))
        await asyncio.sleep(0)
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task

    asyncio.run(scenario())
    assert sent[0]["status"] == 503
    assert dict(sent[0]["headers"])[b"retry-after"]
    assert b"shutting down" in sent[1]["body"]


# --- through the API --------------------------------------------------------------------------


@pytest.fixture(scope="module")
def client(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TestClient]:
    tmp = tmp_path_factory.mktemp("hardening5")
    settings = Settings(
        state_dir=tmp,
        api_token=TOKEN,
        requests={"max_filters": 1, "max_queued_filters": 0, "retry_after_s": 3},
        jobs={"max_pending": 1},
    )
    with TestClient(create_app(settings, TOKEN, sampler_factory=FakeSampler)) as c:
        yield c


def _state(client: TestClient) -> Any:
    return client.app.state.cablecal  # type: ignore[attr-defined]


def test_filter_upload_attacks_through_the_api(
    client: TestClient, calibrated: dict[str, int]
) -> None:
    url = f"{API}/robots/{calibrated['robot_id']}/filter"
    headers = {**AUTH, "Content-Type": CT}
    for raw, expected in (
        (_body(_part(b'form-data; name="files"; filename="a.mod"'), close=False), "truncated"),
        (_body(_part(b'form-data; filename="a.mod"')), "part 0: its Content-Disposition"),
        (
            _body(
                _part(b'form-data; name="files"; filename="A.mod"'),
                _part(b'form-data; name="files"; filename="a.mod"'),
            ),
            "only in case",
        ),
        (_body(_part(b'form-data; name="files"; filename="CON.mod"')), "reserved device"),
    ):
        r = client.post(url, content=raw, headers=headers)
        assert r.status_code == 422, r.text
        assert expected in r.text, r.text
    ok = _body(_part(b'form-data; name="files"; filename="a.mod"'))
    r = client.post(url + "?dry_run=true", content=ok, headers=headers)
    assert r.status_code == 200, r.text


def test_a_filter_beyond_the_gate_is_a_429_with_retry_after(
    client: TestClient, calibrated: dict[str, int]
) -> None:
    gate = _state(client).gates["filter"]
    gate.active = gate.running  # as if a filter ran (max_queued_filters = 0)
    try:
        r = client.post(
            f"{API}/robots/{calibrated['robot_id']}/filter",
            content=_body(_part(b'form-data; name="files"; filename="a.mod"')),
            headers={**AUTH, "Content-Type": CT},
        )
    finally:
        gate.active = 0
    assert r.status_code == 429 and r.headers["retry-after"] == "3", r.text


def test_pending_jobs_are_capped(client: TestClient, calibrated: dict[str, int]) -> None:
    jobs = _state(client).jobs
    jobs._tasks[-1] = None  # one job pending (max_pending = 1)
    try:
        r = client.post(
            f"{API}/campaigns/{calibrated['campaign_id']}/identifications",
            json={"method": "lm"},
            headers=AUTH,
        )
    finally:
        del jobs._tasks[-1]
    assert r.status_code == 429 and r.headers["retry-after"] == "3", r.text
    assert "max_pending" in r.json()["detail"]


def test_readiness_takes_the_posts_holdout_and_seed(
    client: TestClient, calibrated: dict[str, int]
) -> None:
    url = f"{API}/campaigns/{calibrated['campaign_id']}/identification-readiness"
    for holdout in ("random", "grouped"):
        r = client.get(url, params={"holdout": holdout, "seed": 3}, headers=AUTH)
        assert r.status_code == 200, r.text
        assert isinstance(r.json()["ready"], bool)
    assert client.get(url, params={"holdout": "rows"}, headers=AUTH).status_code == 422
    assert client.get(url, params={"seed": -1}, headers=AUTH).status_code == 422


def test_text_with_format_characters_is_a_422(client: TestClient) -> None:
    for name in ("a\u202eb", "zero\u200bwidth", "line\u2028sep", "\ufeffbom"):
        r = client.post(f"{API}/campaigns", json={"name": name}, headers=AUTH)
        assert r.status_code == 422, (name, r.text)
    r = client.post(f"{API}/campaigns", json={"name": "n", "notes": "a\u2029b"}, headers=AUTH)
    assert r.status_code == 422, r.text


def test_list_pages_of_large_rows_are_capped(client: TestClient) -> None:
    assert client.get(f"{API}/campaigns?limit=500", headers=AUTH).status_code == 200
    assert client.get(f"{API}/campaigns?limit=501", headers=AUTH).status_code == 422


def test_writes_below_the_free_space_reserve_are_a_507_and_write_nothing(
    client: TestClient, calibrated: dict[str, int]
) -> None:
    settings = _state(client).settings
    before = client.get(f"{API}/campaigns", headers=AUTH).json()
    kept = settings.requests.disk_reserve_mb
    settings.requests.disk_reserve_mb = 1_000_000  # more than this disk has
    try:
        r = client.post(f"{API}/campaigns", json={"name": "full"}, headers=AUTH)
        assert r.status_code == 507 and "disk_reserve_mb" in r.json()["detail"], r.text
        r = client.post(
            f"{API}/campaigns/{calibrated['campaign_id']}/samples/import",
            content=b"q1,q2,q3,q4,q5,q6,L\n0,0,0,0,0,0,500\n",
            headers={**AUTH, "Content-Type": "text/csv"},
        )
        assert r.status_code == 507, r.text
        r = client.post(
            f"{API}/campaigns/{calibrated['campaign_id']}/identifications",
            json={"method": "lm"},
            headers=AUTH,
        )
        assert r.status_code == 507, r.text
    finally:
        settings.requests.disk_reserve_mb = kept
    assert client.get(f"{API}/campaigns", headers=AUTH).json() == before


def test_the_csv_export_streams_the_included_samples(
    client: TestClient, calibrated: dict[str, int]
) -> None:
    r = client.get(f"{API}/campaigns/{calibrated['campaign_id']}/samples?format=csv", headers=AUTH)
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/csv")
    lines = r.text.splitlines()
    assert lines[0].startswith("q1,q2,q3,q4,q5,q6,L") and len(lines) == 81


# --- a real server: the head limit, slow readers --------------------------------------------


@pytest.fixture
def server(tmp_path: Path) -> Iterator[str]:
    app = _app = create_app(
        Settings(state_dir=tmp_path, api_token=TOKEN), TOKEN, sampler_factory=FakeSampler
    )
    _SERVED["app"] = _app
    with served_app(app, **uvicorn_options(16, send_timeout_s=1.0)) as (host, port):
        yield f"{host}:{port}"


_SERVED: dict[str, Any] = {}


def _connect(addr: str) -> socket.socket:
    host, port = addr.split(":")
    return socket.create_connection((host, int(port)), timeout=5)


def test_a_head_padded_with_whitespace_counts_every_byte(server: str) -> None:
    for pad, status in ((MAX_HEAD_BYTES + 1024, b"431"), (1024, b"200")):
        head = b"GET /api/v1/health HTTP/1.1\r\nHost: x\r\nConnection: close\r\n"
        head += b"X-Pad: a" + b" " * pad + b"b\r\n\r\n"
        s = _connect(server)
        s.sendall(head)  # one write: h11's bound on an incomplete head never applies
        answer = closed_by_server(s, 5.0) or b""
        assert answer.startswith(b"HTTP/1.1 " + status), (pad, answer[:120])


def test_a_body_refused_before_it_is_read_closes_the_connection(server: str) -> None:
    """A 404 sent after 1 KiB of a declared 300 KiB body: the answer says ``connection:
    close`` and the server closes without waiting for the rest."""
    s = _connect(server)
    s.sendall(
        b"POST /api/v1/robots/999/filter HTTP/1.1\r\nHost: x\r\nAuthorization: "
        + AUTH["Authorization"].encode()
        + b"\r\nContent-Type: multipart/form-data; boundary=Bnd7\r\n"
        b"Content-Length: 307200\r\n\r\n" + b"x" * 1024
    )
    answer = closed_by_server(s, 5.0) or b""
    assert answer.startswith(b"HTTP/1.1 404"), answer[:200]
    assert b"connection: close" in answer.lower()


def test_a_slow_reader_is_disconnected_after_the_send_timeout(server: str) -> None:
    """A page of 500 campaigns with the longest notes (about 10 MB of JSON, more than the
    kernel's socket buffers hold) to a client that reads none of it."""
    store = _SERVED["app"].state.cablecal.store
    robot_id = int(store.ensure_builtin_robot("hsr-jr680")["id"])
    for k in range(500):
        store.create_campaign(f"c{k}", robot_id, '"' * 10_000)
    host, port = server.split(":")
    s = socket.socket()
    s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)  # before connect: a small window
    s.connect((host, int(port)))
    s.sendall(
        b"GET /api/v1/campaigns?limit=500 HTTP/1.1\r\nHost: x\r\nAuthorization: "
        + AUTH["Authorization"].encode()
        + b"\r\n\r\n"
    )
    time.sleep(3.0)  # read nothing for three times the send timeout
    got = b""
    s.settimeout(5.0)
    try:
        while chunk := s.recv(1 << 16):
            got += chunk
    except (ConnectionResetError, TimeoutError):
        pass
    finally:
        s.close()
    head, _, body = got.partition(b"\r\n\r\n")
    fields = dict(line.split(b": ", 1) for line in head.split(b"\r\n")[1:])
    length = int(fields[b"content-length"])
    assert len(body) < length, "the whole response was delivered to a client that did not read"


def test_a_program_of_targets_outside_the_limits_is_a_409(
    client: TestClient, calibrated: dict[str, int]
) -> None:
    """The README's conflicts: joints outside the robot model's limits are a 409 naming the
    target, not a 422 on ``query.format``."""
    from calib.models import builtin_model

    limits = builtin_model("hsr-jr680").joint_limits_deg.tolist()
    mid = [(lo + hi) / 2 for lo, hi in limits]
    rows = [{f"q{j + 1}": v for j, v in enumerate(mid)}]
    for j in range(6):  # every joint at each of its limits: a correction crosses some
        for bound in limits[j]:
            q = list(mid)
            q[j] = float(bound)
            rows.append({f"q{k + 1}": v for k, v in enumerate(q)})
    url = f"{API}/robots/{calibrated['robot_id']}/compensate"
    r = client.post(url, json=rows, headers=AUTH)
    assert r.status_code == 200, r.text
    flagged = [k for k, row in enumerate(r.json()["rows"]) if "outside_limits" in row["flags"]]
    assert flagged, r.json()["rows"]
    r = client.post(url + "?format=fanuc-ls", json=rows, headers=AUTH)
    assert r.status_code == 409, r.text
    assert f"target {flagged[0] + 1}" in r.json()["detail"]


def test_a_large_campaign_is_checked_and_submitted_in_a_worker_process(
    client: TestClient, calibrated: dict[str, int], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Above CHILD_CHECK_SAMPLES (set to 0 here) the check and the snapshot run in a worker
    process on the store opened read-only: readiness and the POST agree, the job runs."""
    from daemon.api.routes.identifications import identifications

    monkeypatch.setattr(identifications, "CHILD_CHECK_SAMPLES", 0)
    cid = calibrated["campaign_id"]
    url = f"{API}/campaigns/{cid}/identification-readiness"
    assert client.get(url, headers=AUTH).json()["ready"] is True
    r = client.get(url, params={"test_fraction": 0.99}, headers=AUTH)
    assert r.status_code == 200 and r.json()["ready"] is False and r.json()["reason"]
    r = client.post(
        f"{API}/campaigns/{cid}/identifications",
        json={"method": "lm", "test_fraction": 0.99},
        headers=AUTH,
    )
    assert r.status_code == 409, r.text
    r = client.post(f"{API}/campaigns/{cid}/identifications", json={"method": "lm"}, headers=AUTH)
    assert r.status_code == 202, r.text
    job_id = r.json()["id"]
    deadline = time.monotonic() + 120
    while (job := client.get(f"{API}/identifications/{job_id}", headers=AUTH).json())[
        "status"
    ] not in ("succeeded", "failed", "cancelled"):
        assert time.monotonic() < deadline
        time.sleep(0.2)
    assert job["status"] == "succeeded", job
