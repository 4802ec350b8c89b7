"""The service's lifespan: its parts started in order and stopped in reverse.

store → jobs → sensor watch → sampler (its sink, given when it is built, is the store watched
by the sensor watch) → auto capture (:class:`daemon.monitors.autocapture.AutoCapture`, which
the watch then follows, resumed as the store says) → hold-check monitor. The
app itself is assembled in :mod:`daemon.api.main`.
"""

from __future__ import annotations

import contextlib
import gc
import logging
import sys
from collections.abc import AsyncIterator, Callable
from typing import Any

from fastapi import FastAPI

from daemon.api.deps import AppState
from daemon.api.http.offload import gates_of, per_minute_of
from daemon.api.min_samples import MinSamplesCache
from daemon.config import Settings
from daemon.jobs.manager import JobManager
from daemon.monitors.autocapture import AutoCapture
from daemon.monitors.holdcheck import HoldCheckMonitor
from daemon.monitors.watch import SensorWatch
from daemon.process.lifecycle import STOPPED, record_start
from daemon.store import Store

log = logging.getLogger("cablecal.serve")

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
    """The sampler of the configured drivers, given their typed settings; its sink is the
    store watched by the sensor watch (:meth:`SensorWatch.wrap`), which is built first."""
    from daemon.sampler.core import Sampler
    from drivers import make_indicator, make_robot

    s = state.settings
    sink = state.watch.wrap(state.store)
    return Sampler(make_indicator(s.indicator), make_robot(s.robot), s.sampler, sink)


def make_lifespan(
    settings: Settings, token: str, sampler_factory: SamplerFactory | None = None
) -> Callable[[FastAPI], contextlib.AbstractAsyncContextManager[None]]:
    """The app's lifespan: builds the :class:`AppState` into ``app.state.cablecal``."""

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        for note in settings.deprecations():
            log.warning(note)
        state = build_state(settings, token)
        app.state.cablecal = state
        record_start(state.store)  # and unclean_shutdown if the previous run did not stop
        await state.jobs.start()
        try:
            state.watch = SensorWatch(
                state.store, settings.watch.step_settings(), enabled=settings.watch.enabled
            )
            state.sampler = (sampler_factory or default_sampler)(state)
            await state.sampler.start()
            state.auto = AutoCapture(state.store, state.sampler)
            state.watch.start(state.auto)
            state.auto.resume()
            state.hold_check = HoldCheckMonitor(state.store, settings.hold_check, state.auto)
            await state.hold_check.start()
            # Everything built so far (modules, schemas, models) lives as long as the process:
            # out of the collector's sight, a full collection during a large import has far
            # less to walk, and holds the event loop that much shorter.
            gc.freeze()
            sys.setswitchinterval(SWITCH_INTERVAL_S)
            yield
        finally:
            for gate in state.gates.values():
                gate.close()  # from now on heavy work is a 503
            if state.hold_check is not None:
                await state.hold_check.stop()
            if state.watch is not None:
                await state.watch.stop()
            if state.sampler is not None:
                await state.sampler.stop()
            await state.jobs.stop()
            state.store.record_event(STOPPED, None, "cablecal serve stopped")
            state.store.close()

    return lifespan
