"""Assemble the FastAPI app: the lifespan (:mod:`daemon.api.lifespan`), routers,
error handlers (:mod:`daemon.api.errors`), the request guard (:mod:`daemon.api.guard`: auth,
then body limits), the latency middleware (:mod:`daemon.api.latency`), the operator page and
/docs (:mod:`daemon.api.web`)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from fastapi import Depends, FastAPI

from daemon.api import errors
from daemon.api.deps import AppState, bound_path_ids, finite_queries
from daemon.api.errors import API_KINDS, error_responses, not_found_detail
from daemon.api.guard import API_PREFIX, RequestGuard
from daemon.api.latency import LatencyMiddleware
from daemon.api.lifespan import make_lifespan
from daemon.api.methods import OptionsMiddleware
from daemon.api.offload import CancelledIs503
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
        # Every {..._id} bounded and every number query finite, whatever the route.
        dependencies=[Depends(bound_path_ids), Depends(finite_queries)],
        # Any request may be over its peer's rate (daemon.api.guard): 429 with Retry-After.
        responses=error_responses(429),
    )
    # The last added is the outermost: latency sees the guard's 401 and 413 too.
    limits = settings.requests
    app.add_middleware(
        RequestGuard,
        token=token,
        public_reads=settings.public_reads,
        prefix=API_PREFIX,
        rate_per_s=limits.rate_per_s,
        rate_burst=limits.rate_burst,
        rate_refusal_delay_s=limits.rate_refusal_delay_s,
    )
    app.add_middleware(LatencyMiddleware, prefix=API_PREFIX)
    app.add_middleware(OptionsMiddleware, routes_of=app)  # OPTIONS: 204 + Allow, no token
    app.add_middleware(CancelledIs503)  # cancelled at shutdown: 503, not uvicorn's 500
    for module in (
        system,
        live,
        campaigns,
        identifications,
        reports,
        robots,
        plans,
        compensate,
        program_filter,
        verify,
        check_poses,
        checks,
        watch,
    ):
        app.include_router(module.router, prefix=API_PREFIX)
    app.include_router(system.metrics_router)
    errors.install(app)

    mount_web(app)
    return app
