"""Timing by an injected clock: calib reads no clock itself (docs/architecture.md); a caller
that wants a result's ``elapsed_s`` (the daemon, the CLI, a bench) passes one in."""

from __future__ import annotations

from collections.abc import Callable

#: A clock in seconds, e.g. ``time.perf_counter``: calib reads no clock itself, the caller
#: (the daemon, the CLI, a bench) injects one where a result reports its ``elapsed_s``.
Clock = Callable[[], float]


class Timer:
    """``elapsed_s`` by an injected :data:`Clock`; without one (None) the run is not timed
    and :meth:`elapsed` is 0."""

    def __init__(self, clock: Clock | None) -> None:
        self.clock = clock
        self.start = 0.0 if clock is None else clock()

    def elapsed(self) -> float:
        return 0.0 if self.clock is None else self.clock() - self.start
