"""Which methods a path allows: ``OPTIONS`` on every path, and the ``Allow`` header of a 405.

RFC 9110: a 405 carries ``Allow`` with every method of the resource, and ``OPTIONS`` answers
with it. Starlette's own 405 names only the methods of the first route whose path matched
(``GET /campaigns`` and ``POST /campaigns`` are two routes), and it has no ``OPTIONS``. Both
read the app's route table here, so a new route needs nothing: :func:`allowed_methods` asks
every route whether it would take the request with each method.
"""

from __future__ import annotations

from collections.abc import Awaitable, Callable, MutableMapping
from typing import Any, Final

from starlette.routing import Match

Scope = MutableMapping[str, Any]
Message = MutableMapping[str, Any]
Receive = Callable[[], Awaitable[Message]]
Send = Callable[[Message], Awaitable[None]]
ASGIApp = Callable[[Scope, Receive, Send], Awaitable[None]]

#: Methods asked of each route, in the order ``Allow`` lists them.
METHODS: Final = ("GET", "HEAD", "POST", "PUT", "PATCH", "DELETE")


def allowed_methods(app: Any, scope: Scope) -> list[str]:
    """The methods some route of ``app`` takes for ``scope``'s path, plus ``OPTIONS``; an
    empty list when no route has the path (a 404)."""
    routes = getattr(getattr(app, "router", app), "routes", [])
    allowed = []
    for method in METHODS:
        probe = {**scope, "method": method}
        if any(route.matches(probe)[0] == Match.FULL for route in routes):
            allowed.append(method)
    return [*allowed, "OPTIONS"] if allowed else []


def allow_header(app: Any, scope: Scope) -> str:
    """The ``Allow`` header value for ``scope``'s path (see :func:`allowed_methods`)."""
    return ", ".join(allowed_methods(app, scope))


class OptionsMiddleware:
    """Pure ASGI middleware: ``OPTIONS`` on a known path is a 204 with ``Allow`` (no token
    needed: it tells no more than the public OpenAPI schema); on an unknown path a 404."""

    def __init__(self, app: ASGIApp, *, routes_of: Any) -> None:
        self.app = app
        self.routes_of = routes_of  # the FastAPI app, whose routes are read per request

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or scope["method"] != "OPTIONS":
            await self.app(scope, receive, send)
            return
        methods = allowed_methods(self.routes_of, scope)
        if not methods:
            body = b'{"detail":"Not Found"}'
            headers = [(b"content-type", b"application/json")]
            status = 404
        else:
            body, headers, status = b"", [(b"allow", ", ".join(methods).encode())], 204
        headers.append((b"content-length", str(len(body)).encode()))
        await send({"type": "http.response.start", "status": status, "headers": headers})
        await send({"type": "http.response.body", "body": body})
