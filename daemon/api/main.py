"""Assemble the FastAPI app: the lifespan (:mod:`daemon.api.lifespan`), routers,
error handlers (:mod:`daemon.api.errors`), the request guard (:mod:`daemon.api.guard`: auth,
then body limits), the latency middleware, the operator page and /docs (:mod:`daemon.api.web`)."""

from __future__ import annotations

import time
from collections.abc import Awaitable, Callable, MutableMapping
from typing import Any

from fastapi import Depends, FastAPI

from daemon import metrics
from daemon.api import errors
from daemon.api.deps import AppState, bound_path_ids
from daemon.api.errors import API_KINDS, not_found_detail
from daemon.api.guard import RequestGuard
from daemon.api.lifespan import make_lifespan
from daemon.api.methods import OptionsMiddleware
from daemon.api.routes import (
    campaigns,
    check_poses,
    checks,
    compensate,
    identifications,
    live,
    plans,
    program_filter,
    reports,
    robots,
    system,
    verify,
    watch,
)
from daemon.api.web import mount_web
from daemon.config import Settings

API_PREFIX = "/api/v1"

Scope = MutableMapping[str, Any]
Message = MutableMapping[str, Any]
Receive = Callable[[], Awaitable[Message]]
Send = Callable[[Message], Awaitable[None]]
ASGIApp = Callable[[Scope, Receive, Send], Awaitable[None]]


class LatencyMiddleware:
    """Pure ASGI middleware: request latency per route template and status into
    :data:`daemon.metrics.HTTP_LATENCY` (no per-request task, unlike BaseHTTPMiddleware)."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

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
            route = scope.get("route")
            template = getattr(route, "path", None) or "unmatched"
            # Routes of included routers carry their path without the router's prefix.
            if (
                route is not None
                and scope["path"].startswith(API_PREFIX)
                and not template.startswith(API_PREFIX)
            ):
                template = API_PREFIX + template
            metrics.HTTP_LATENCY.labels(scope["method"], template, str(code[0])).observe(
                time.perf_counter() - t0
            )


__all__ = ["API_KINDS", "API_PREFIX", "create_app", "not_found_detail"]


def create_app(
    settings: Settings,
    token: str,
    *,
    sampler_factory: Callable[[AppState], Any] | None = None,
) -> FastAPI:
    """The service. ``sampler_factory(state)`` builds the sampler (default: the configured
    drivers, :func:`daemon.api.lifespan.default_sampler`); the parts are started and stopped
    in :func:`daemon.api.lifespan.make_lifespan`."""
    app = FastAPI(
        title="cablecal",
        version=system.VERSION,
        summary="Robot calibration with a drawstring sensor: campaigns, captures, identification.",
        lifespan=make_lifespan(settings, token, sampler_factory),
        docs_url=None,  # served by mount_web from local files
        redoc_url=None,
        dependencies=[Depends(bound_path_ids)],  # every {..._id} bounded, whatever the route
    )
    # The last added is the outermost: latency sees the guard's 401 and 413 too.
    app.add_middleware(
        RequestGuard, token=token, public_reads=settings.public_reads, prefix=API_PREFIX
    )
    app.add_middleware(LatencyMiddleware)
    app.add_middleware(OptionsMiddleware, routes_of=app)  # OPTIONS: 204 + Allow, no token
    for module in (system, live, campaigns, identifications, reports, robots, plans,
                   compensate, program_filter, verify, check_poses, checks,
                   watch):  # fmt: skip
        app.include_router(module.router, prefix=API_PREFIX)
    app.include_router(system.metrics_router)
    errors.install(app)

    mount_web(app)
    return app
