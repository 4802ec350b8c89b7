"""Assemble the FastAPI app: lifespan (store → jobs → sampler, stopped in reverse), routers,
error handlers (:mod:`daemon.api.errors`), the request guard (:mod:`daemon.api.guard`: auth,
then body limits), the latency middleware (:mod:`daemon.api.latency`), the operator page and
/docs (:mod:`daemon.api.web`)."""

from __future__ import annotations

import contextlib
import gc
import logging
import sys
from collections.abc import AsyncIterator, Callable
from typing import Any

from fastapi import Depends, FastAPI

from daemon.api import errors
from daemon.api.deps import AppState, bound_path_ids, finite_queries
from daemon.api.errors import API_KINDS, not_found_detail
from daemon.api.guard import API_PREFIX, RequestGuard
from daemon.api.latency import LatencyMiddleware
from daemon.api.methods import OptionsMiddleware
from daemon.api.min_samples import MinSamplesCache
from daemon.api.routes import (
    apply,
    campaigns,
    identifications,
    live,
    plans,
    reports,
    robots,
    system,
    watch,
)
from daemon.api.web import mount_web
from daemon.config import Settings
from daemon.drift import DriftMonitor
from daemon.jobs import JobManager
from daemon.lifecycle import record_start
from daemon.store import Store
from daemon.watch import SensorWatch

log = logging.getLogger("cablecal.service")

#: The interpreter's GIL switch interval while the service runs [s] (see the lifespan).
SWITCH_INTERVAL_S = 0.001

__all__ = ["API_KINDS", "API_PREFIX", "create_app", "not_found_detail"]


def build_state(settings: Settings, token: str) -> AppState:
    """Open the store (creating or migrating it) and create the job manager."""
    settings.state_dir.mkdir(parents=True, exist_ok=True)
    store = Store(settings.database_path)
    return AppState(
        settings=settings,
        token=token,
        store=store,
        jobs=JobManager(store, settings.jobs),
        min_samples=MinSamplesCache(store),
    )


def create_app(
    settings: Settings,
    token: str,
    *,
    sampler_factory: Callable[[AppState], Any] | None = None,
) -> FastAPI:
    """The service. ``sampler_factory(state)`` builds the sampler (default: the configured
    drivers via :func:`daemon.sampler.build_sampler`); it is started in the lifespan."""

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        state = build_state(settings, token)
        app.state.cablecal = state
        record_start(state.store)  # and unclean_shutdown if the previous run did not stop
        await state.jobs.start()
        try:
            state.sampler = (sampler_factory or _default_sampler)(state)
            await state.sampler.start()
            state.watch = SensorWatch(state.store, settings.watch.step_settings(),
                                      state.sampler, enabled=settings.watch.enabled)  # fmt: skip
            if hasattr(state.sampler, "sink"):  # test doubles may store nothing
                state.sampler.sink = state.watch.wrap(state.sampler.sink)
            for campaign in state.store.auto_capture_campaigns():
                cid = int(campaign["id"])
                state.sampler.set_auto(
                    cid,
                    anchor=str(campaign.get("auto_anchor") or "A"),
                    known_poses_deg=state.store.poses_deg(cid),
                )
                log.info("auto capture resumed", extra={"campaign_id": cid})
            state.drift = DriftMonitor(state.store, settings.drift, state.sampler)
            await state.drift.start()
            # Everything built so far (modules, schemas, models) lives as long as the process:
            # out of the collector's sight, a full collection during a large import takes
            # milliseconds instead of ~100 ms on the event loop.
            gc.freeze()
            # Worker threads (CSV imports, plans, compensation) share the GIL with the event
            # loop: a 1 ms switch interval (default 5 ms) hands it back to the loop sooner.
            # (The /health figures of a large import: bench/design_figures.md.)
            sys.setswitchinterval(SWITCH_INTERVAL_S)
            yield
        finally:
            if state.drift is not None:
                await state.drift.stop()
            if state.watch is not None:
                await state.watch.stop()
            if state.sampler is not None:
                await state.sampler.stop()
            await state.jobs.stop()
            state.store.record_event("daemon_stopped", None, "cablecal serve stopped")
            state.store.close()

    app = FastAPI(
        title="cablecal",
        version=system.VERSION,
        summary="Robot calibration with a drawstring sensor: campaigns, captures, identification.",
        lifespan=lifespan,
        docs_url=None,  # served by mount_web from local files
        redoc_url=None,
        # Every {..._id} bounded and every number query finite, whatever the route.
        dependencies=[Depends(bound_path_ids), Depends(finite_queries)],
    )
    # The last added is the outermost: latency sees the guard's 401 and 413 too.
    app.add_middleware(
        RequestGuard, token=token, public_reads=settings.public_reads, prefix=API_PREFIX
    )
    app.add_middleware(LatencyMiddleware, prefix=API_PREFIX)
    app.add_middleware(OptionsMiddleware, routes_of=app)  # OPTIONS: 204 + Allow, no token
    for module in (system, live, campaigns, identifications, reports, robots, plans, apply,
                   watch):  # fmt: skip
        app.include_router(module.router, prefix=API_PREFIX)
    app.include_router(system.metrics_router)
    errors.install(app)

    mount_web(app)
    return app


def _default_sampler(state: AppState) -> Any:
    from daemon.sampler import build_sampler

    s = state.settings
    return build_sampler(s.indicator.model_dump(), s.robot.model_dump(), s.sampler, state.store)
