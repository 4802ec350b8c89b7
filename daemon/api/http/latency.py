"""Request latency into :data:`daemon.metrics.HTTP_LATENCY`, with labels from closed sets.

Every label value comes from a fixed set, whatever a client sends, so ``/metrics`` cannot be
grown by requests (issue 28: 2,000 requests with 200-byte methods had grown it to 33 MB):

- ``method``: one of :data:`METHODS`, else :data:`OTHER`;
- ``route``: the template of the app route that matched (``/api/v1/campaigns/{campaign_id}``;
  the route table is fixed when the app is built), never the raw path; else :data:`OTHER`;
- ``status``: the three digits of a status code the app sent (100..599), else :data:`OTHER`.
"""

from __future__ import annotations

import time
from collections.abc import Awaitable, Callable, MutableMapping
from typing import Any, Final

from daemon import metrics
from daemon.api.http.allow import METHODS as ROUTE_METHODS

Scope = MutableMapping[str, Any]
Message = MutableMapping[str, Any]
Receive = Callable[[], Awaitable[Message]]
Send = Callable[[Message], Awaitable[None]]
ASGIApp = Callable[[Scope, Receive, Send], Awaitable[None]]

#: The label value of anything outside a closed set.
OTHER: Final = "other"
#: Methods that get their own ``method`` label.
METHODS: Final = frozenset({*ROUTE_METHODS, "OPTIONS"})


def method_label(method: str) -> str:
    """``method`` if it is one of :data:`METHODS`, else :data:`OTHER`."""
    return method if method in METHODS else OTHER


def route_label(scope: Scope, prefix: str) -> str:
    """The template of the route that matched ``scope`` (with ``prefix`` when the route was
    included under it), else :data:`OTHER`."""
    template = getattr(scope.get("route"), "path", None)
    if not isinstance(template, str) or not template:
        return OTHER
    # Routes of included routers may carry their path without the router's prefix.
    if str(scope.get("path", "")).startswith(prefix) and not template.startswith(prefix):
        template = prefix + template
    return template


def status_label(status: int) -> str:
    """A status code as its three digits, :data:`OTHER` outside 100..599."""
    return str(status) if 100 <= status <= 599 else OTHER


class LatencyMiddleware:
    """Pure ASGI middleware: request latency per method, route template and status into
    :data:`daemon.metrics.HTTP_LATENCY` (no per-request task, unlike BaseHTTPMiddleware)."""

    def __init__(self, app: ASGIApp, *, prefix: str) -> None:
        self.app = app
        self.prefix = prefix

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        t0 = time.perf_counter()
        code = [500]

        async def send_wrapper(message: Message) -> None:
            if message["type"] == "http.response.start":
                code[0] = int(message["status"])
            await send(message)

        try:
            await self.app(scope, receive, send_wrapper)
        finally:
            metrics.HTTP_LATENCY.labels(
                method_label(str(scope["method"])),
                route_label(scope, self.prefix),
                status_label(code[0]),
            ).observe(time.perf_counter() - t0)
