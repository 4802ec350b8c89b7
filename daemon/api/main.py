"""Assemble the FastAPI app: the lifespan (:mod:`daemon.api.lifespan`), routers,
error handlers (:mod:`daemon.api.errors`), the request guard (:mod:`daemon.api.http.guard`: auth,
then body limits), the latency middleware (:mod:`daemon.api.http.latency`), the operator page and
/docs (:mod:`daemon.api.web`)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from fastapi import Depends, FastAPI

from daemon import __version__
from daemon.api import errors
from daemon.api.deps import AppState, bound_path_ids, finite_queries
from daemon.api.errors import API_KINDS, error_responses, not_found_detail
from daemon.api.http.allow import OptionsMiddleware
from daemon.api.http.guard import API_PREFIX, RequestGuard
from daemon.api.http.latency import LatencyMiddleware
from daemon.api.http.offload import CancelledIs503
from daemon.api.lifespan import make_lifespan
from daemon.api.routes import live, system
from daemon.api.routes.campaigns import campaigns, captures, plans, samples, sensor_moved
from daemon.api.routes.identifications import identifications, reports, verify
from daemon.api.routes.robots import check_poses, checks, compensate, program_filter, robots
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
    drivers and the sink ``state.watch.wrap(state.store)``,
    :func:`daemon.api.lifespan.default_sampler`); the parts are started and stopped
    in :func:`daemon.api.lifespan.make_lifespan`."""
    app = FastAPI(
        title="cablecal",
        version=__version__,
        summary="Robot calibration with a drawstring sensor: campaigns, captures, identification.",
        lifespan=make_lifespan(settings, token, sampler_factory),
        docs_url=None,  # served by mount_web from local files
        redoc_url=None,
        # Every {..._id} bounded and every number query finite, whatever the route.
        dependencies=[Depends(bound_path_ids), Depends(finite_queries)],
        # Any request may be over its peer's rate (daemon.api.http.guard): 429 with Retry-After.
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
        captures,
        samples,
        identifications,
        reports,
        robots,
        plans,
        compensate,
        program_filter,
        verify,
        check_poses,
        checks,
        sensor_moved,
    ):
        app.include_router(module.router, prefix=API_PREFIX)
    app.include_router(system.metrics_router)
    errors.install(app)

    mount_web(app)
    return app
