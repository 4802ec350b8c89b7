"""Issue 28, items 2 and 10: one client cannot take every connection, and the request-head
limit holds however the head arrives. A real uvicorn server on loopback runs the app with the
bounds of ``cablecal serve`` (daemon/api/server.py), some shortened so the test takes seconds.

On loopback every client would be 127.0.0.1, so "another client" binds its socket to another
loopback address (127.0.0.2, 127.0.0.3): a distinct peer address for the server.
"""

from __future__ import annotations

import select
import socket
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
from helpers import closed_by_server, served_app
from test_service import AUTH, TOKEN, FakeSampler, _settings

from daemon.api import server as server_module
from daemon.api.main import create_app
from daemon.api.server import MAX_HEAD_BYTES, uvicorn_options

PER_CLIENT = 64  # the test's max_connections_per_client
SLOW = 600  # slow sockets from one peer
HEAD_TIMEOUT_S = 2.0


def _serve(tmp_path: Path, options: dict[str, Any]) -> Iterator[tuple[str, int]]:
    # Requests in a tight loop from one peer, over its request rate (the rate is
    # test_api_hardening6's): no rate here, these tests are about connections.
    settings = _settings(tmp_path, requests={"rate_per_s": 0})
    app = create_app(settings, TOKEN, sampler_factory=FakeSampler)
    with served_app(app, **options) as addr:
        yield addr


@pytest.fixture
def served(tmp_path: Path) -> Callable[..., Iterator[tuple[str, int]]]:
    return lambda **options: _serve(tmp_path, options)


def _slow_socket(addr: tuple[str, int], source: str = "127.0.0.1") -> socket.socket:
    """A connection that has sent part of a request head and nothing more."""
    s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    s.settimeout(5)
    s.bind((source, 0))
    s.connect(addr)
    s.sendall(b"GET /api/v1/health HTTP/1.1\r\nHost: x\r\nX-Slow: ")
    return s


def _client(addr: tuple[str, int], source: str) -> httpx.Client:
    transport = httpx.HTTPTransport(local_address=source)
    return httpx.Client(base_url=f"http://{addr[0]}:{addr[1]}", transport=transport, timeout=5)


@pytest.mark.slow
def test_600_slow_sockets_from_one_peer_leave_another_client_served(served: Any) -> None:
    """600 slow heads from 127.0.0.1: 64 are held (then closed by the head timeout), the rest
    are refused with 503 at once; 127.0.0.2 gets every /health and an authorised read
    answered 200 all the while, within a second each."""
    options = uvicorn_options(PER_CLIENT, head_timeout_s=HEAD_TIMEOUT_S)
    for addr in served(**options):
        t_open = time.monotonic()
        held = [_slow_socket(addr) for _ in range(SLOW)]
        try:
            with _client(addr, "127.0.0.2") as other:
                codes, worst_s = [], 0.0
                while time.monotonic() < t_open + HEAD_TIMEOUT_S - 0.3:
                    t0 = time.monotonic()
                    codes.append(other.get("/api/v1/health").status_code)
                    codes.append(other.get("/api/v1/campaigns", headers=AUTH).status_code)
                    worst_s = max(worst_s, time.monotonic() - t0)
                assert len(codes) >= 4 and set(codes) == {200}, codes
                assert worst_s < 1.0, worst_s
            # The same peer is at its cap: a further connection of its own is a 503.
            with _client(addr, "127.0.0.1") as same:
                r = same.get("/api/v1/health")
                assert r.status_code == 503, r.text
                assert "max_connections_per_client" in r.json()["detail"]
            answers = [closed_by_server(s, HEAD_TIMEOUT_S + 3.0) for s in held]
            elapsed_s = time.monotonic() - t_open
        finally:
            for s in held:
                s.close()
        refused = [a for a in answers if a and a.startswith(b"HTTP/1.1 503 ")]
        dropped = [a for a in answers if a == b""]  # held, then closed without a word
        assert len(dropped) == PER_CLIENT, (len(dropped), len(refused))
        assert len(refused) == SLOW - PER_CLIENT
        assert elapsed_s < HEAD_TIMEOUT_S + 4.0, elapsed_s  # the held heads closed on time
        with _client(addr, "127.0.0.1") as same:  # and the peer is served again
            assert same.get("/api/v1/health").status_code == 200


@pytest.mark.slow
def test_past_the_connection_limit_the_reserve_serves_health_and_loopback(
    served: Any, monkeypatch: pytest.MonkeyPatch
) -> None:
    """With every ordinary connection taken, a non-loopback peer still gets /health (and
    only /health) on the reserve, and a loopback peer gets everything. 127.0.0.3 plays a
    remote peer (the test cannot have a real one)."""
    monkeypatch.setattr(server_module, "is_loopback", lambda host: host == "127.0.0.1")
    options = uvicorn_options(100, head_timeout_s=5.0, max_connections=40, reserve_connections=8)
    for addr in served(**options):
        held = [_slow_socket(addr, "127.0.0.2") for _ in range(40)]
        try:
            time.sleep(0.2)
            with _client(addr, "127.0.0.3") as remote:
                assert remote.get("/api/v1/health").status_code == 200
                r = remote.get("/api/v1/campaigns", headers=AUTH)
                assert r.status_code == 503 and "only the health check" in r.text, r.text
            with _client(addr, "127.0.0.1") as local:
                assert local.get("/api/v1/campaigns", headers=AUTH).status_code == 200
            more = [_slow_socket(addr, "127.0.0.2") for _ in range(8)]  # fills the reserve
            held += more
            time.sleep(0.2)
            with _client(addr, "127.0.0.1") as local:
                r = local.get("/api/v1/health")
                assert r.status_code == 503 and "server busy" in r.text, r.text
        finally:
            for s in held:
                s.close()


def _send_head(addr: tuple[str, int], head: bytes, pieces: int) -> bytes:
    """Send ``head`` in ``pieces``; stop sending once the server answers (it closes then)."""
    with socket.create_connection(addr, timeout=5) as s:
        step = -(-len(head) // pieces)
        for i in range(0, len(head), step):
            s.sendall(head[i : i + step])
            if pieces > 1 and select.select([s], [], [], 0.005)[0]:
                break
        return closed_by_server(s, 5.0) or b""


@pytest.mark.parametrize("pieces", [1, 40])
def test_the_request_head_limit_holds_in_one_read_or_many(served: Any, pieces: int) -> None:
    """A head over MAX_HEAD_BYTES is a 431 whether it arrives at once or in 40 pieces; one
    just under it is served."""
    for addr in served(**uvicorn_options(PER_CLIENT)):
        for size, status in ((MAX_HEAD_BYTES + 2048, b"431"), (MAX_HEAD_BYTES - 512, b"200")):
            filler = b"X-Fill: " + b"a" * (size - 200) + b"\r\n"
            head = b"GET /api/v1/health HTTP/1.1\r\nHost: x\r\nConnection: close\r\n"
            head += filler + b"\r\n"
            answer = _send_head(addr, head, pieces)
            assert answer.startswith(b"HTTP/1.1 " + status), (size, answer[:200])
            if status == b"431":
                assert f"limit of {MAX_HEAD_BYTES} bytes".encode() in answer
