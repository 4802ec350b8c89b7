"""The HTTP server's bounds against slow and many clients (uvicorn + h11), used by
``cablecal serve``.

A client that opens connections and sends a request slowly, or not at all, holds a socket
and a file descriptor each. The bounds, each at the layer that sees it:

- **Request head**: :class:`BoundedH11Protocol` closes a connection whose request line and
  headers are not complete :data:`HEAD_TIMEOUT_S` after it opened or after its previous
  response (uvicorn itself has no such timeout; its keep-alive timer stops at the first byte).
  A head over :data:`MAX_HEAD_BYTES` is a 431, whether it arrives in many reads (h11's bound
  on an incomplete event) or in one (checked on the parsed head).
- **Request body**: :class:`daemon.api.http.guard.RequestGuard` answers 408 when a started body
  stalls for :data:`daemon.api.http.guard.BODY_GAP_TIMEOUT_S` or is not complete within
  :data:`daemon.api.http.guard.BODY_TIMEOUT_S`.
- **Slow readers**: a client that reads none of a response for ``send_timeout_s`` (the
  ``[requests]`` setting) is disconnected, and the response's buffer freed.
- **Connections per client**: one peer address holds at most ``max_connections_per_client``
  connections at once (the setting in :mod:`daemon.config`); a further one is answered 503
  and closed at once, so a few clients cannot take every connection.
- **Connections in all**: at most :data:`MAX_CONNECTIONS` at once; beyond it
  :data:`RESERVE_CONNECTIONS` more are kept for loopback peers and for ``GET /api/v1/health``
  (a request on a reserve connection from another peer is a 503), so the health check and a
  local operator still get through when the rest is full. Idle keep-alive connections close
  after :data:`KEEP_ALIVE_S`.

So held-open connections are dropped within seconds and never crowd out ``/health``.
"""

from __future__ import annotations

import asyncio
import ipaddress
import json
from collections import Counter
from typing import Any, Final

import h11
from uvicorn.protocols.http.h11_impl import H11Protocol

from daemon.api.http.guard import HEALTH_PATH
from daemon.config import RequestSettings

#: Time for a request line and headers to arrive, from the connection's start or its previous
#: response [s].
HEAD_TIMEOUT_S: Final = 10.0
#: Idle time after a response before a keep-alive connection is closed [s].
KEEP_ALIVE_S: Final = 5
#: Connections open at once from all peers; beyond it only the reserve.
MAX_CONNECTIONS: Final = 512
#: Further connections kept for loopback peers and the health check.
RESERVE_CONNECTIONS: Final = 32
#: Largest request head: request line and headers [bytes] (h11's default, stated here so it
#: has one home).
MAX_HEAD_BYTES: Final = 16 * 1024


def head_bytes(event: h11.Request) -> int:
    """The size of a parsed request head [bytes]: request line, headers and the blank line as
    sent without optional whitespace (a lower bound of what arrived)."""
    line = len(event.method) + len(event.target) + len(b"HTTP/") + len(event.http_version) + 4
    return line + sum(len(k) + len(v) + 4 for k, v in event.headers.raw_items()) + 2


def is_loopback(host: str | None) -> bool:
    """Whether a peer address is a loopback address."""
    try:
        return host is not None and ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


class _HeadBoundConnection(h11.Connection):
    """h11's connection that also refuses a complete head over the limit (h11 bounds only an
    incomplete one) and remembers the status a protocol error asks for. The head's size is
    every byte it took from the receive buffer, whitespace and line folding included (the
    parsed fields alone would let a head padded with spaces through)."""

    error_status = 400

    def next_event(self) -> Any:
        buffer = getattr(self, "_receive_buffer", None)  # h11's own (0.14 .. 0.16)
        before = len(buffer) if buffer is not None else 0
        try:
            event = super().next_event()
        except h11.RemoteProtocolError as exc:
            self.error_status = exc.error_status_hint
            raise
        if not isinstance(event, h11.Request):
            return event
        taken = before - len(buffer) if buffer is not None else 0
        if max(taken, head_bytes(event)) > MAX_HEAD_BYTES:
            self.error_status = 431
            raise h11.RemoteProtocolError("request head too large", error_status_hint=431)
        return event


def _health_only(app: Any) -> Any:
    """``app`` for ``GET``/``HEAD /api/v1/health`` only; any other request is a 503."""

    async def gate(scope: Any, receive: Any, send: Any) -> None:
        path = str(scope.get("path", "")).rstrip("/")
        if scope.get("type") != "http" or (
            path == HEALTH_PATH and scope.get("method") in ("GET", "HEAD")
        ):
            await app(scope, receive, send)
            return
        body = json.dumps(
            {
                "detail": f"server busy: over {MAX_CONNECTIONS} connections; "
                "only the health check is served"
            }
        ).encode()
        headers = [
            (b"content-type", b"application/json"),
            (b"connection", b"close"),
            (b"content-length", str(len(body)).encode()),
        ]
        await send({"type": "http.response.start", "status": 503, "headers": headers})
        await send({"type": "http.response.body", "body": body})

    return gate


class BoundedH11Protocol(H11Protocol):
    """uvicorn's h11 protocol with a deadline for each request head, a bound on its size and
    the connection caps (see the module). :func:`bounded_protocol` sets the per-client cap."""

    head_timeout_s: float = HEAD_TIMEOUT_S
    # The setting's default; `cablecal serve` passes the configured one (uvicorn_options).
    send_timeout_s: float = RequestSettings.model_fields["send_timeout_s"].default
    max_per_client: int = MAX_CONNECTIONS
    max_connections: int = MAX_CONNECTIONS
    reserve_connections: int = RESERVE_CONNECTIONS

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.conn = _HeadBoundConnection(h11.SERVER, MAX_HEAD_BYTES)

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        super().connection_made(transport)
        self._head_timer: asyncio.TimerHandle | None = None
        self._peer = self.client[0] if self.client else None
        self._counted = False
        refusal = self._admit()
        if refusal is not None:
            self._refuse(refusal)
            return
        self._arm_head_timer()

    def _peers(self) -> Counter[str | None]:
        """Open connections per peer address, shared by the server's connections."""
        peers: Counter[str | None] | None = getattr(self.server_state, "cablecal_peers", None)
        if peers is None:
            peers = Counter()
            self.server_state.cablecal_peers = peers  # type: ignore[attr-defined]
        return peers

    def _admit(self) -> str | None:
        """Count this connection in, or the reason it is refused."""
        peers = self._peers()
        others = len(self.connections) - 1  # uvicorn has added this one
        if peers[self._peer] >= self.max_per_client:
            return (
                f"too many connections from {self._peer}: at most {self.max_per_client} at "
                "once (max_connections_per_client)"
            )
        if others >= self.max_connections + self.reserve_connections:
            return f"server busy: over {self.max_connections} connections"
        if others >= self.max_connections and not is_loopback(self._peer):
            self.app = _health_only(self.app)
        peers[self._peer] += 1
        self._counted = True
        return None

    def _refuse(self, reason: str) -> None:
        """A 503 naming ``reason`` and the connection closed, before any request is read."""
        body = json.dumps({"detail": reason}).encode()
        self.transport.write(
            b"HTTP/1.1 503 Service Unavailable\r\ncontent-type: application/json\r\n"
            b"connection: close\r\ncontent-length: " + str(len(body)).encode() + b"\r\n\r\n" + body
        )
        self.transport.close()

    def data_received(self, data: bytes) -> None:
        if self._counted:  # a refused connection reads nothing
            super().data_received(data)

    def send_400_response(self, msg: str) -> None:
        if self.conn.error_status != 431:  # type: ignore[attr-defined]
            super().send_400_response(msg)
            return
        detail = f"request head: larger than the limit of {MAX_HEAD_BYTES} bytes".encode()
        headers = [(b"content-type", b"text/plain; charset=utf-8"), (b"connection", b"close")]
        self.transport.write(self.conn.send(h11.Response(status_code=431, headers=headers)) or b"")
        self.transport.write(self.conn.send(h11.Data(data=detail)) or b"")
        self.transport.write(self.conn.send(h11.EndOfMessage()) or b"")
        self.transport.close()

    def pause_writing(self) -> None:
        """The client stopped reading (the socket's buffer is full): it has ``send_timeout_s``
        to read on before the connection is aborted and the response's buffer freed."""
        super().pause_writing()
        self._cancel_send_timer()
        self._send_timer: asyncio.TimerHandle | None = self.loop.call_later(
            self.send_timeout_s, self._send_timeout
        )

    def resume_writing(self) -> None:
        super().resume_writing()
        self._cancel_send_timer()

    def _cancel_send_timer(self) -> None:
        timer = getattr(self, "_send_timer", None)
        if timer is not None:
            timer.cancel()
            self._send_timer = None

    def _send_timeout(self) -> None:
        self._send_timer = None
        if self.flow is not None and self.flow.write_paused:
            self.transport.abort()  # drops what is buffered; the app's send returns

    def on_response_complete(self) -> None:
        super().on_response_complete()
        self._arm_head_timer()

    def connection_lost(self, exc: Exception | None) -> None:
        self._cancel_head_timer()
        self._cancel_send_timer()
        if getattr(self, "_counted", False):
            peers = self._peers()
            peers[self._peer] -= 1
            if peers[self._peer] <= 0:
                del peers[self._peer]
            self._counted = False
        super().connection_lost(exc)

    def _arm_head_timer(self) -> None:
        self._cancel_head_timer()
        if not self.transport.is_closing():
            self._head_timer = self.loop.call_later(self.head_timeout_s, self._head_timeout)

    def _cancel_head_timer(self) -> None:
        timer = getattr(self, "_head_timer", None)
        if timer is not None:
            timer.cancel()
            self._head_timer = None

    def _head_timeout(self) -> None:
        """No request in progress (its head never completed): close the connection."""
        self._head_timer = None
        if self.cycle is None or self.cycle.response_complete:
            self.transport.close()


def bounded_protocol(max_per_client: int, **bounds: Any) -> type[BoundedH11Protocol]:
    """:class:`BoundedH11Protocol` with a per-client cap (and, for tests, other bounds given
    by their class attribute names, e.g. ``head_timeout_s=1.0``)."""
    attrs = {"max_per_client": max_per_client, **bounds}
    return type("BoundedH11Protocol", (BoundedH11Protocol,), attrs)


def uvicorn_options(max_per_client: int, **bounds: Any) -> dict[str, Any]:
    """The bounds above as ``uvicorn.Config`` keyword arguments; ``max_per_client`` is the
    ``max_connections_per_client`` setting."""
    protocol = bounded_protocol(max_per_client, **bounds)
    return {
        "http": protocol,
        "timeout_keep_alive": KEEP_ALIVE_S,
        # uvicorn's own 503 limit only behind ours: the protocol admits connections.
        "limit_concurrency": protocol.max_connections + protocol.reserve_connections + 1,
        "h11_max_incomplete_event_size": MAX_HEAD_BYTES,
    }
