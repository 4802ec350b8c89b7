"""The request guard: the bearer token first, then the body-size bound while the body streams.

A pure ASGI middleware in front of the routes, so that neither costs memory before it is
decided:

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
import json
import re
from collections.abc import Awaitable, Callable, MutableMapping
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
    ) -> None:
        self.app = app
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


async def _reply(send: Send, status: int, detail: str, extra: dict[str, str] | None = None) -> None:
    """A JSON error ``{"detail": ...}`` sent straight from the middleware."""
    body = json.dumps({"detail": detail}).encode()
    headers = [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode())]
    headers += [(k.encode(), v.encode()) for k, v in (extra or {}).items()]
    await send({"type": "http.response.start", "status": status, "headers": headers})
    await send({"type": "http.response.body", "body": body})
