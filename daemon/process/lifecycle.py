"""The daemon's start in the event log, and the detection of an unclean stop before it.

Every start records a ``daemon_started`` event (with the pid) and every clean stop a
``daemon_stopped`` event (the lifespan's shutdown in :func:`daemon.api.main.create_app`). A
start that finds the newest of the two to be a ``daemon_started`` knows that the previous run
ended without its shutdown: SIGKILL, a crash, the watchdog's SIGABRT or power loss. It then
records an ``unclean_shutdown`` event naming when that run started (and its pid) before its own
``daemon_started``. The store's events are committed and synced (WAL, ``synchronous=FULL``), so
the evidence survives whatever ended the previous run; no separate marker file can go stale.
"""

from __future__ import annotations

import datetime as dt
import logging
import os
from typing import TYPE_CHECKING, Any

from daemon import metrics

if TYPE_CHECKING:
    from daemon.store import Store

log = logging.getLogger("cablecal.lifecycle")

STARTED = "daemon_started"
STOPPED = "daemon_stopped"
UNCLEAN = "unclean_shutdown"


def _newest(events: Store, kind: str) -> dict[str, Any] | None:
    rows = events.list_events(kind=kind, limit=1)
    return dict(rows[-1]) if rows else None


def iso_utc(t_wall: float) -> str:
    """``t_wall`` [s since the epoch] as ISO 8601 UTC, to the second."""
    return dt.datetime.fromtimestamp(t_wall, dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


def unclean_previous_run(events: Store) -> dict[str, Any] | None:
    """The ``daemon_started`` event of a previous run that has no ``daemon_stopped`` after
    it, or None (first start, or the previous run stopped cleanly)."""
    started = _newest(events, STARTED)
    if started is None:
        return None
    stopped = _newest(events, STOPPED)
    if stopped is not None and int(stopped["id"]) > int(started["id"]):
        return None
    return started


def record_start(events: Store) -> dict[str, Any] | None:
    """Record this start; first an ``unclean_shutdown`` event if the previous run did not stop
    cleanly. Returns that event's detail, or None.

    The detail: ``previous_started_at`` [s since the epoch], ``previous_started_iso`` (UTC),
    ``previous_pid`` (None for a run that did not record it), ``previous_event_id``.
    """
    previous = unclean_previous_run(events)
    detail: dict[str, Any] | None = None
    if previous is not None:
        t_wall = float(previous["t_wall"])
        pid = (previous.get("detail") or {}).get("pid")
        detail = {
            "previous_started_at": t_wall,
            "previous_started_iso": iso_utc(t_wall),
            "previous_pid": pid,
            "previous_event_id": int(previous["id"]),
        }
        who = "" if pid is None else f" (pid {pid})"
        message = (
            f"the previous run{who}, started {iso_utc(t_wall)}, did not stop cleanly "
            "(killed, crashed or power lost)"
        )
        log.warning(message)
        events.record_event(UNCLEAN, None, message, detail)
    events.record_event(STARTED, None, "cablecal serve started", {"pid": os.getpid()})
    # The count of unclean stops the store knows: a counter that carries over restarts.
    metrics.UNCLEAN_SHUTDOWNS.inc(len(events.list_events(kind=UNCLEAN, limit=10_000)))
    return detail
