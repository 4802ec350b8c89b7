"""Liveness, status, Prometheus metrics and the test-only debug hooks."""

from __future__ import annotations

import time
from typing import Annotated, Any

from fastapi import APIRouter, HTTPException, Query, Request, Response
from prometheus_client import CONTENT_TYPE_LATEST, generate_latest
from pydantic import BaseModel, Field

from daemon import __version__, metrics
from daemon.api.deps import MAX_ID, PAGE_DEFAULT, ReadAuth, State, WriteAuth, link_next
from daemon.api.errors import error_responses
from daemon.api.schemas import Health, ServiceStatus
from daemon.store import EventRow

router = APIRouter(tags=["system"], responses=error_responses(400, 401, 413, 422))
metrics_router = APIRouter(tags=["system"])


@router.get("/health", summary="Liveness")
async def health(state: State) -> Health:
    """Always open. ``status`` is ``ok`` while the service answers."""
    return {
        "status": "ok",
        "version": __version__,
        "uptime_s": round(time.monotonic() - state.started_monotonic_s, 3),
    }


@router.get("/status", summary="Devices, sampler mode and rates", dependencies=[ReadAuth])
async def get_status(state: State) -> ServiceStatus:
    """Each device's connection state, last reading and its age, last error (with the last
    frames in hex), poll rate [Hz]; the sampler's mode and auto-capture campaign; jobs; the
    last hold check (``hold_check``: ``state`` ok/not_held/failed/none, ``last_check_at``,
    ``rms_mm``, ``threshold_mm``, ``running``); the live sensor watch (``watch``: ``moves``
    not undone, per campaign the running fit and the last residual;
    :meth:`daemon.monitors.watch.SensorWatch.status`)."""
    st: dict[str, Any] = state.sampler.status() if state.sampler is not None else {}
    return {
        "devices": st.get("devices", {}),
        "sampler": st.get("sampler"),
        "jobs": {"active": state.jobs.active},
        "hold_check": state.hold_check.status() if state.hold_check is not None else None,
        "watch": state.watch.status() if state.watch is not None else None,
        "uptime_s": round(time.monotonic() - state.started_monotonic_s, 3),
    }


@router.get("/events", summary="Device and daemon events (paginated)", dependencies=[ReadAuth])
def list_events(
    state: State,
    request: Request,
    response: Response,
    kind: str | None = Query(
        None, max_length=64, description="e.g. link_down, link_up, capture_rejected"
    ),
    since_id: int | None = Query(
        None, ge=0, le=MAX_ID, description="Only events with a larger id (the cursor)."
    ),
    limit: int = Query(100, ge=1, le=PAGE_DEFAULT),
) -> list[EventRow]:
    """Device errors, link drops and recoveries, rejected captures, daemon starts and stops,
    newest last. Without ``since_id``: the newest ``limit`` events; with it: the first
    ``limit`` after it. A full page has a ``Link: <…?since_id=<last id>…>; rel="next"``
    header (follow it to read on)."""
    rows = state.store.list_events(kind=kind, since_id=since_id, limit=limit)
    link_next(request, response, rows, limit, cursor="since_id")
    return rows


@metrics_router.get(
    "/metrics",
    summary="Prometheus metrics",
    response_class=Response,
    responses={200: {"content": {"text/plain": {"schema": {"type": "string"}}}}},
)
async def get_metrics(state: State) -> Response:
    """Prometheus text format (always open: counters only, no secrets)."""
    if state.sampler is not None:
        state.sampler.update_age_metrics()
    return Response(generate_latest(metrics.REGISTRY), media_type=CONTENT_TYPE_LATEST)


class Hang(BaseModel):
    """Block the event loop (debug_routes only)."""

    seconds: Annotated[float, Field(gt=0, le=120)]


@router.post("/debug/hang", include_in_schema=False, dependencies=[WriteAuth])
async def debug_hang(state: State, body: Hang) -> dict[str, float]:
    """Simulate a hung main loop: a blocking sleep ON the event loop. Tests use it to show the
    systemd watchdog pings stop. Only with ``debug_routes = true``."""
    if not state.settings.debug_routes:
        raise HTTPException(404, "debug routes are disabled")
    time.sleep(body.seconds)  # deliberately blocking
    return {"slept_s": body.seconds}
