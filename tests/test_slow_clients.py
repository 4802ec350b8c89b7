"""Issue 21: clients that hold connections open with a partial request (300 such connections
stayed open with no end before) are dropped within the bounds of daemon/api/http/server.py and the
request guard, and /health answers all the while. A real uvicorn server on loopback runs the
app with the bounds shortened to 1-2 s, as ``cablecal serve`` configures it."""

from __future__ import annotations

import socket
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from helpers import closed_by_server, served_app
from test_service import AUTH, TOKEN, FakeSampler, _settings

from daemon.api.http import guard
from daemon.api.http.server import uvicorn_options
from daemon.api.main import create_app

HELD = 150  # connections of each kind held open


@pytest.fixture
def server(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[str]:
    monkeypatch.setattr(guard, "BODY_GAP_TIMEOUT_S", 1.0)
    monkeypatch.setattr(guard, "BODY_TIMEOUT_S", 2.0)
    # 2 x HELD requests from one peer at once, over its request rate's burst (the rate is
    # test_api_hardening6's): no rate here.
    settings = _settings(tmp_path, requests={"rate_per_s": 0})
    app = create_app(settings, TOKEN, sampler_factory=FakeSampler)
    with served_app(app, **uvicorn_options(2 * HELD + 10, head_timeout_s=1.0)) as (host, port):
        yield f"{host}:{port}"


def _open(addr: str, data: bytes) -> socket.socket:
    host, port = addr.split(":")
    s = socket.create_connection((host, int(port)), timeout=5)
    s.sendall(data)
    return s


@pytest.mark.slow
def test_partial_heads_and_bodies_are_dropped_and_health_answers(server: str) -> None:
    auth = AUTH["Authorization"].encode()
    heads = [
        _open(server, b"GET /api/v1/health HTTP/1.1\r\nHost: x\r\nX-Slow: ") for _ in range(HELD)
    ]
    body = b'{"name": "slow", '
    head = b"POST /api/v1/campaigns HTTP/1.1\r\nHost: x\r\nAuthorization: " + auth
    post = head + b"\r\nContent-Type: application/json\r\nContent-Length: 1000\r\n\r\n" + body
    bodies = [_open(server, post) for _ in range(HELD)]
    try:
        worst_s = 0.0
        with httpx.Client(base_url=f"http://{server}", timeout=5) as client:
            t_end = time.monotonic() + 1.5
            while time.monotonic() < t_end:  # while all 2 x HELD connections are held
                t0 = time.monotonic()
                assert client.get("/api/v1/health").status_code == 200
                worst_s = max(worst_s, time.monotonic() - t0)
                time.sleep(0.05)
        assert worst_s < 1.0, worst_s
        for s in heads:
            assert closed_by_server(s, 5.0) == b""  # closed without a word: no request yet
        for s in bodies:
            answer = closed_by_server(s, 5.0)
            assert answer is not None and answer.startswith(b"HTTP/1.1 408 "), answer
            assert b"body: incomplete after" in answer
    finally:
        for s in heads + bodies:
            s.close()
    with httpx.Client(base_url=f"http://{server}", headers=AUTH, timeout=5) as client:
        assert client.get("/api/v1/campaigns").json() == []  # the stalled creates stored nothing
