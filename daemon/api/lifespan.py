"""The service's lifespan: its parts started in order and stopped in reverse.

store → jobs → sampler → sensor watch (the sampler's sink wrapped) → auto capture
(:class:`daemon.autocapture.AutoCapture`, resumed as the store says) → drift monitor. The
app itself is assembled in :mod:`daemon.api.main`.
"""

from __future__ import annotations

import contextlib
import gc
import sys
from collections.abc import AsyncIterator, Callable
from typing import Any

from fastapi import FastAPI

from daemon.api.deps import AppState
from daemon.api.min_samples import MinSamplesCache
from daemon.api.offload import gates_of, per_minute_of
from daemon.autocapture import AutoCapture
from daemon.config import Settings
from daemon.holdcheck import HoldCheckMonitor
from daemon.jobs import JobManager
from daemon.lifecycle import STOPPED, record_start
from daemon.store import Store
from daemon.watch import SensorWatch

#: The interpreter's GIL switch interval while the service runs [s]: worker threads (CSV
#: imports, plans, compensation) share the GIL with the event loop, and 1 ms (Python's
#: default is 5 ms) hands it back to the loop sooner. (The /health figures of a large
#: import: bench/design_figures.md.)
SWITCH_INTERVAL_S = 0.001

SamplerFactory = Callable[[AppState], Any]


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
        gates=gates_of(settings),
        per_minute=per_minute_of(settings),
    )


def default_sampler(state: AppState) -> Any:
    """The sampler of the configured drivers, given their typed settings."""
    from daemon.sampler import Sampler
    from drivers import make_indicator, make_robot

    s = state.settings
    return Sampler(make_indicator(s.indicator), make_robot(s.robot), s.sampler, state.store)


def watch_captures(sampler: Any, watch: SensorWatch) -> None:
    """The sampler's sink wrapped, so that the watch tests each stored capture (test
    doubles without a sink store nothing) and a refused capture is stored with its pose."""
    if hasattr(sampler, "sink"):
        sampler.sink = watch.wrap(sampler.sink)
    if hasattr(sampler, "status"):
        watch.joints_now = lambda: robot_joints_deg(sampler.status())


def robot_joints_deg(status: dict[str, Any]) -> list[float] | None:
    """The robot's latest joints [deg] (6) from the sampler's ``status()``, or None."""
    reading = ((status.get("devices") or {}).get("robot") or {}).get("last_reading") or {}
    value = reading.get("value")
    if not isinstance(value, list | tuple) or len(value) != 6:
        return None
    return [float(v) for v in value]


def make_lifespan(
    settings: Settings, token: str, sampler_factory: SamplerFactory | None = None
) -> Callable[[FastAPI], contextlib.AbstractAsyncContextManager[None]]:
    """The app's lifespan: builds the :class:`AppState` into ``app.state.cablecal``."""

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        state = build_state(settings, token)
        app.state.cablecal = state
        record_start(state.store)  # and unclean_shutdown if the previous run did not stop
        await state.jobs.start()
        try:
            state.sampler = (sampler_factory or default_sampler)(state)
            await state.sampler.start()
            state.auto = AutoCapture(state.store, state.sampler)
            state.watch = SensorWatch(
                state.store,
                settings.watch.step_settings(),
                state.auto,
                enabled=settings.watch.enabled,
            )
            watch_captures(state.sampler, state.watch)
            state.auto.resume()
            state.drift = HoldCheckMonitor(state.store, settings.drift, state.auto)
            await state.drift.start()
            # Everything built so far (modules, schemas, models) lives as long as the process:
            # out of the collector's sight, a full collection during a large import has far
            # less to walk, and holds the event loop that much shorter.
            gc.freeze()
            sys.setswitchinterval(SWITCH_INTERVAL_S)
            yield
        finally:
            for gate in state.gates.values():
                gate.close()  # from now on heavy work is a 503
            if state.drift is not None:
                await state.drift.stop()
            if state.watch is not None:
                await state.watch.stop()
            if state.sampler is not None:
                await state.sampler.stop()
            await state.jobs.stop()
            state.store.record_event(STOPPED, None, "cablecal serve stopped")
            state.store.close()

    return lifespan
