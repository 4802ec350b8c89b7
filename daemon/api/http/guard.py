"""The request guard: the peer's request rate, the bearer token, then the body-size bound
while the body streams.

A pure ASGI middleware in front of the routes, so that none costs memory before it is
decided:

- **Rate per peer.** Each peer address has a token bucket (:class:`TokenBuckets`: the
  ``[requests]`` settings ``rate_per_s`` and ``rate_burst``; a request takes one token and
  one more per :data:`BYTES_PER_TOKEN` of its body); a request that finds too few is a 429
  with ``Retry-After``, its body unread and its connection closed, answered after
  ``rate_refusal_delay_s`` so that a client that ignores Retry-After cannot make the event
  loop answer refusals as fast as it sends. Only the REST API's requests are counted (not the
  operator page's files, nor ``/metrics``), ``GET /health`` not, and no request without a
  network peer (an in-process ASGI client, a Unix socket): the key is the peer's IP address.

- **Auth before the body.** Under ``/api/v1``, every request but ``GET /health`` needs the
  token (reads too, unless ``public_reads``). Without it the answer is 401 before a byte of the
  body is read, so a client without the token can neither make the daemon buffer a large body
  nor learn anything from a validation error. (The routes keep their own auth dependencies;
  they also document the security scheme in OpenAPI.)
- **Body time.** A body that pauses for :data:`BODY_GAP_TIMEOUT_S` or is not complete
  within :data:`BODY_TIMEOUT_S` is a 408, and the connection closes (a client holding partial
  bodies open cannot pile up connections; :mod:`daemon.api.http.server` bounds the request head).
- **Unread bodies.** A response sent before the body was read to its end (a refusal after
  the body's first bytes) closes the connection: the rest is neither parsed nor waited for.
- **Body limits while streaming.** A ``Content-Length`` over the limit is refused at once; a
  body without one (chunked) is counted as it arrives and refused with 413 as soon as the
  count passes the limit, so at most one chunk beyond the limit is ever held.
"""

from __future__ import annotations

import asyncio
import hmac
import ipaddress
import json
import math
import re
import time
from collections.abc import Awaitable, Callable, Hashable, MutableMapping
from typing import Any, Final

from starlette.exceptions import HTTPException

Scope = MutableMapping[str, Any]
Message = MutableMapping[str, Any]
Receive = Callable[[], Awaitable[Message]]
Send = Callable[[Message], Awaitable[None]]
ASGIApp = Callable[[Scope, Receive, Send], Awaitable[None]]

#: The prefix of the REST API (the routes' home: daemon.api.main).
API_PREFIX: Final = "/api/v1"
#: Largest JSON request body [bytes]. The largest legitimate one is a campaign with an uploaded
#: robot model (about 2 kB) and notes of at most 10 000 characters (40 kB as UTF-8).
MAX_JSON_BYTES: Final = 256 * 1024
#: Largest CSV import [bytes]: 2000 poses are about 150 kB; 20 MB is over 250 000 rows.
MAX_IMPORT_BYTES: Final = 20 * 1024 * 1024
#: Largest compensation body [bytes], CSV or JSON: 10 000 pose rows are about 1 MB.
MAX_COMPENSATE_BYTES: Final = 4 * 1024 * 1024

#: Largest program-filter upload [bytes] (``POST /robots/{id}/filter``): all files together.
MAX_FILTER_BYTES: Final = 16 * 1024 * 1024

#: Bytes of a request body that count as one more request of the peer's rate [bytes]: a
#: 300 KiB upload counts about 6 requests; a 16 MiB one the whole burst.
BYTES_PER_TOKEN: Final = 64 * 1024

#: Longest pause in a request body that has started [s]: a stalled body is a 408.
BODY_GAP_TIMEOUT_S: Final = 10.0
#: Longest time to receive a whole request body [s] (20 MiB at 1 MiB/s would still fit).
BODY_TIMEOUT_S: Final = 60.0

_IMPORT_PATH = re.compile(re.escape(API_PREFIX) + r"/campaigns/[^/]+/samples/import/?")
_COMPENSATE_PATH = re.compile(re.escape(API_PREFIX) + r"/robots/[^/]+/compensate/?")
_FILTER_PATH = re.compile(re.escape(API_PREFIX) + r"/robots/[^/]+/filter/?")
#: The liveness route: open without the token (and kept a connection by daemon.api.http.server).
HEALTH_PATH: Final = API_PREFIX + "/health"
_OPEN_PATHS = frozenset({HEALTH_PATH})
_READ_METHODS = frozenset({"GET", "HEAD"})

#: The header that ends a connection after its response.
CLOSE: Final = (b"connection", b"close")

UNAUTHORIZED_DETAIL: Final = (
    "missing or wrong bearer token (Authorization: Bearer <CABLECAL_API_TOKEN>)"
)


def token_matches(authorization: str | None, token: str) -> bool:
    """Whether an ``Authorization`` header carries ``Bearer <token>`` (constant-time)."""
    if not authorization:
        return False
    scheme, _, credentials = authorization.partition(" ")
    if scheme.lower() != "bearer":
        return False
    return hmac.compare_digest(credentials.strip().encode(), token.encode())


class TokenBuckets:
    """A token bucket per key: ``burst`` tokens at most, refilled at ``rate_per_s``; each
    request takes one.

    Memory is bounded: beyond :attr:`max_keys` keys, the buckets that are full again (their
    key idle long enough) are forgotten, and if none is, the oldest half.

    Parameters
    ----------
    rate_per_s : float
        Tokens added per second (0: no limit, :meth:`take` always grants).
    burst : int
        The bucket's size [tokens].
    clock : callable returning float
        Seconds, monotonic (tests pass their own).
    """

    max_keys: int = 4096

    def __init__(
        self, rate_per_s: float, burst: int, clock: Callable[[], float] = time.monotonic
    ) -> None:
        self.rate_per_s = rate_per_s
        self.burst = burst
        self.clock = clock
        self._buckets: dict[Hashable, tuple[float, float]] = {}  # key -> (tokens, at [s])

    def take(self, key: Hashable, cost: float = 1.0) -> float:
        """Take ``cost`` tokens (at most the burst) of ``key``'s bucket: 0.0 when granted,
        else the seconds until they are there (nothing taken)."""
        if self.rate_per_s <= 0:
            return 0.0
        cost = min(cost, float(self.burst))
        now = self.clock()
        tokens, at = self._buckets.get(key, (float(self.burst), now))
        tokens = min(float(self.burst), tokens + (now - at) * self.rate_per_s)
        if tokens >= cost:
            if key not in self._buckets and len(self._buckets) >= self.max_keys:
                self._forget(now)
            self._buckets[key] = (tokens - cost, now)
            return 0.0
        self._buckets[key] = (tokens, now)
        return (cost - tokens) / self.rate_per_s

    def _forget(self, now: float) -> None:
        full_s = self.burst / self.rate_per_s
        idle = [k for k, (_, at) in self._buckets.items() if now - at >= full_s]
        for k in idle or list(self._buckets)[: len(self._buckets) // 2]:
            del self._buckets[k]


def peer_key(scope: Scope) -> str | None:
    """The peer's IP address, the key of its rate; None without a network peer."""
    client = scope.get("client")
    if not client:
        return None
    try:
        return str(ipaddress.ip_address(str(client[0])))
    except ValueError:
        return None


def request_cost(scope: Scope, path: str) -> float:
    """What a request takes of its peer's bucket [tokens]: one, and one more for each
    :data:`BYTES_PER_TOKEN` of its body (``Content-Length``; a body without one, chunked,
    counts as the largest its route takes, :func:`body_limit`): a flood of uploads is held to
    fewer requests than a page's polls, which have no body."""
    size = 0
    for name, value in scope.get("headers", ()):
        if name == b"content-length":
            size = int(value) if value.strip().isdigit() else 0
            break
        if name == b"transfer-encoding" and b"chunked" in value.lower():
            size = body_limit(path)
    return 1.0 + size / BYTES_PER_TOKEN


def retry_after(wait_s: float) -> str:
    """A ``Retry-After`` value [whole s, at least 1] for a wait of ``wait_s``."""
    return str(max(1, math.ceil(wait_s)))


def body_limit(path: str) -> int:
    """The largest body [bytes] a request to ``path`` may carry."""
    if _IMPORT_PATH.fullmatch(path):
        return MAX_IMPORT_BYTES
    if _FILTER_PATH.fullmatch(path):
        return MAX_FILTER_BYTES
    return MAX_COMPENSATE_BYTES if _COMPENSATE_PATH.fullmatch(path) else MAX_JSON_BYTES


def too_large(limit: int) -> HTTPException:
    """The 413 of a body over ``limit`` bytes."""
    return HTTPException(413, f"body: larger than the limit of {limit} bytes")


class RequestGuard:
    """Auth, then the body bound; see the module docstring.

    Parameters
    ----------
    app : ASGI app
    token : str
        The bearer token.
    public_reads : bool
        Serve GET and HEAD under ``/api/v1`` without the token.
    prefix : str
        The REST prefix the token guards.
    body_gap_timeout_s, body_timeout_s : float
        Longest pause within a body and longest whole body [s]; then 408.
    rate_per_s, rate_burst, rate_refusal_delay_s
        The ``[requests]`` rate settings (:class:`daemon.config.RequestSettings`); the
        defaults: no limit.
    """

    def __init__(
        self,
        app: ASGIApp,
        *,
        token: str,
        public_reads: bool,
        prefix: str,
        body_gap_timeout_s: float | None = None,
        body_timeout_s: float | None = None,
        rate_per_s: float = 0.0,
        rate_burst: int = 1,
        rate_refusal_delay_s: float = 0.0,
    ) -> None:
        self.app = app
        self.rates = TokenBuckets(rate_per_s, rate_burst)
        self.rate_refusal_delay_s = rate_refusal_delay_s
        self.token = token
        self.public_reads = public_reads
        self.prefix = prefix
        # The module's constants unless given (read here, so a test may shorten them).
        self.body_gap_timeout_s = body_gap_timeout_s or BODY_GAP_TIMEOUT_S
        self.body_timeout_s = body_timeout_s or BODY_TIMEOUT_S

    def _needs_token(self, method: str, path: str) -> bool:
        if not (path == self.prefix or path.startswith(self.prefix + "/")):
            return False
        if path.rstrip("/") in _OPEN_PATHS and method in _READ_METHODS:
            return False
        return not (self.public_reads and method in _READ_METHODS)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        path, method = str(scope["path"]), str(scope["method"])
        if await self._over_rate(scope, method, path, send):
            return
        headers = {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in scope["headers"]}
        if self._needs_token(method, path) and not token_matches(
            headers.get("authorization"), self.token
        ):
            await _reply(send, 401, UNAUTHORIZED_DETAIL, {"www-authenticate": "Bearer"})
            return
        limit = body_limit(path)
        declared = headers.get("content-length")
        if declared is not None:
            if not declared.strip().isdigit():
                await _reply(send, 400, f"Content-Length: not a number: {declared!r}")
                return
            if int(declared) > limit:
                await _reply(send, 413, str(too_large(limit).detail))
                return
        received = 0
        body_done = False
        loop = asyncio.get_running_loop()
        body_deadline = loop.time() + self.body_timeout_s

        async def counted() -> Message:
            nonlocal received, body_done
            if body_done:  # after the body: a wait for the client's disconnect, not bounded
                return await receive()
            wait_s = min(self.body_gap_timeout_s, body_deadline - loop.time())
            try:
                async with asyncio.timeout(max(wait_s, 0.0)):
                    message = await receive()
            except TimeoutError:
                raise HTTPException(
                    408,
                    f"body: incomplete after {received} bytes; a request body must not "
                    f"pause for {self.body_gap_timeout_s:g} s or take over "
                    f"{self.body_timeout_s:g} s in all",
                ) from None
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                body_done = not message.get("more_body", False)
                if received > limit:
                    # An HTTPException: FastAPI re-raises it from body parsing, so the
                    # exception handler answers 413 (the route never runs).
                    raise too_large(limit)
            else:
                body_done = True
            return message

        # A body the route answered before reading all of it (a refusal after its first
        # bytes) is not read on: the answer closes the connection, so the server neither
        # parses nor waits for the rest.
        has_body = (declared is not None and int(declared) > 0) or (
            "chunked" in headers.get("transfer-encoding", "").lower()
        )

        async def closing(message: Message) -> None:
            if message["type"] == "http.response.start" and has_body and not body_done:
                message = {**message, "headers": [*message.get("headers", ()), CLOSE]}
            await send(message)

        await self.app(scope, counted, closing)

    async def _over_rate(self, scope: Scope, method: str, path: str, send: Send) -> bool:
        """Whether the request was over its peer's rate (then it has been answered 429)."""
        peer = peer_key(scope)
        if peer is None or not path.startswith(self.prefix + "/"):
            return False  # in-process, or the page's own files and /metrics
        if path.rstrip("/") in _OPEN_PATHS and method in _READ_METHODS:
            return False
        wait_s = self.rates.take(peer, request_cost(scope, path))
        if wait_s <= 0.0:
            return False
        if self.rate_refusal_delay_s > 0:
            await asyncio.sleep(self.rate_refusal_delay_s)
            wait_s = max(0.0, wait_s - self.rate_refusal_delay_s)
        detail = (
            f"too many requests from {peer}: at most {self.rates.rate_per_s:g} a second "
            f"after a burst of {self.rates.burst} ([requests] rate_per_s, rate_burst); "
            f"retry in {retry_after(wait_s)} s"
        )
        extra = {"retry-after": retry_after(wait_s), "connection": "close"}
        await _reply(send, 429, detail, extra)
        return True


async def _reply(send: Send, status: int, detail: str, extra: dict[str, str] | None = None) -> None:
    """A JSON error ``{"detail": ...}`` sent straight from the middleware."""
    body = json.dumps({"detail": detail}).encode()
    headers = [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode())]
    headers += [(k.encode(), v.encode()) for k, v in (extra or {}).items()]
    await send({"type": "http.response.start", "status": status, "headers": headers})
    await send({"type": "http.response.body", "body": body})
