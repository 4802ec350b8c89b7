"""Heavy request work kept off the event loop, bounded, and dropped when its client leaves.

The event loop polls the indicator (the sampler); nothing a client sends may hold it. So the
CPU-heavy work of a request (a program filter; an identification's check and submission, a
CSV import or export, a compensation) runs elsewhere, through a :class:`WorkGate` of its kind:

- **Bounded**: at most ``running`` at once and ``queued`` waiting; a further request is a
  429 with ``Retry-After`` (the ``[requests]`` settings, :class:`daemon.config.RequestSettings`),
  and one that waited ``queue_timeout_s`` in the queue a 503 with ``Retry-After``. After
  shutdown began a request is a 503.
- **Off the loop**: a filter runs in a process of its own
  (:func:`daemon.process.workers.run_in_child`, lower priority, no shared GIL, its memory
  returned when it ends); the rest in a thread.
- **Dropped when the client leaves**: :func:`offload` watches the connection while the work
  waits or runs; a client that disconnects stops a queued request, and kills a process.

:class:`CancelledIs503` answers a request that the server cancels at shutdown with 503
instead of uvicorn's 500.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
from collections.abc import AsyncIterator, Awaitable, Callable
from typing import Any, Final, TypeVar

from fastapi import HTTPException, Request

from daemon.api.http.guard import (
    ASGIApp,
    Message,
    Receive,
    Scope,
    Send,
    TokenBuckets,
    peer_key,
    retry_after,
)

T = TypeVar("T")

#: ``Retry-After`` of a 503 at shutdown [s]: systemd restarts the daemon within seconds.
SHUTDOWN_RETRY_S: Final = 10
SHUTTING_DOWN: Final = "the daemon is shutting down; retry once it is back"


class WorkGate:
    """At most ``running`` works of one kind at once and ``queued`` waiting (see the module).

    Parameters
    ----------
    what : str
        What the work is, for the messages (``program filters``).
    running, queued : int
        Most running at once, most waiting beyond them.
    retry_after_s : int
        ``Retry-After`` of the 429 [s].
    queue_timeout_s : float or None
        Longest wait in the queue [s]; then a 503 with ``Retry-After`` (None: no bound).
    """

    def __init__(
        self,
        what: str,
        running: int,
        queued: int,
        retry_after_s: int,
        queue_timeout_s: float | None = None,
    ) -> None:
        self.what = what
        self.running = running
        self.queued = queued
        self.retry_after_s = retry_after_s
        self.queue_timeout_s = queue_timeout_s
        self.closed = False
        self._slots = asyncio.Semaphore(running)
        self._waiting = 0
        self.active = 0

    def close(self) -> None:
        """Shutdown began: every further request is a 503."""
        self.closed = True

    @contextlib.asynccontextmanager
    async def slot(self, refuse: bool = True) -> AsyncIterator[None]:
        """Hold one of the ``running`` places (after waiting in the queue, if there is room);
        a 429 when the queue is full, a 503 when closed. ``refuse=False``: wait however full
        the queue is (a later step of work already admitted, e.g. the next page of a
        streamed export, whose response has started)."""
        if self.closed:
            raise HTTPException(503, SHUTTING_DOWN, headers={"Retry-After": str(SHUTDOWN_RETRY_S)})
        if refuse and self.active >= self.running and self._waiting >= self.queued:
            raise HTTPException(
                429,
                f"busy: {self.active} {self.what} running and {self._waiting} waiting, the most "
                f"the [requests] settings allow; retry in {self.retry_after_s} s",
                headers={"Retry-After": str(self.retry_after_s)},
            )
        self._waiting += 1
        try:
            async with asyncio.timeout(self.queue_timeout_s if refuse else None):
                await self._slots.acquire()
        except TimeoutError:
            raise HTTPException(
                503,
                f"busy: waited {self.queue_timeout_s:g} s for one of the {self.running} places "
                f"of {self.what} ([requests] queue_timeout_s); retry in {self.retry_after_s} s",
                headers={"Retry-After": str(self.retry_after_s)},
            ) from None
        finally:
            self._waiting -= 1
        self.active += 1
        try:
            yield
        finally:
            self.active -= 1
            self._slots.release()


async def until_disconnected(request: Request) -> None:
    """Return once the client of ``request`` (whose body was read) has disconnected."""
    while True:
        message: Message = await request.receive()
        if message.get("type") == "http.disconnect":
            return


async def offload(
    request: Request,
    gate: WorkGate,
    work: Callable[[], Awaitable[T]],
    *,
    cancel_on_leave: bool = True,
    time_limit_s: float | None = None,
) -> T:
    """``await work()`` within one of ``gate``'s places, dropped when the client leaves:
    while queued always; while running when ``cancel_on_leave`` (a process is killed; a
    thread cannot be stopped and runs to its end, holding its place). ``time_limit_s``
    (only with ``cancel_on_leave``; the program filter's ``[requests] filter_timeout_s``, the
    setting its message names): work running longer is stopped (a process killed) and the
    answer is a 503 with ``Retry-After``.

    Raises
    ------
    HTTPException
        429/503 from the gate; 503 when the client left (nobody reads it) or the work ran
        over ``time_limit_s``.
    """

    async def guarded() -> T:
        async with gate.slot():
            running = asyncio.ensure_future(work())
            try:
                if cancel_on_leave:
                    async with asyncio.timeout(time_limit_s):
                        return await running
                return await asyncio.shield(running)
            except TimeoutError:
                raise HTTPException(
                    503,
                    f"{gate.what}: stopped after {time_limit_s:g} s, the longest one may run "
                    f"([requests] filter_timeout_s); retry when the daemon is less busy, or "
                    f"with fewer or smaller files",
                    headers={"Retry-After": str(gate.retry_after_s)},
                ) from None
            except asyncio.CancelledError:
                if not cancel_on_leave:
                    with contextlib.suppress(BaseException):
                        await running  # keep the place until the thread has ended
                raise

    task = asyncio.ensure_future(guarded())
    gone = asyncio.ensure_future(until_disconnected(request))
    try:
        await asyncio.wait({task, gone}, return_when=asyncio.FIRST_COMPLETED)
    finally:
        if not task.done():
            task.cancel()
            with contextlib.suppress(BaseException):
                await task
        gone.cancel()
        with contextlib.suppress(BaseException):
            await gone
    if task.cancelled():
        raise HTTPException(503, f"client disconnected: its {gate.what} work was stopped")
    return task.result()


class CancelledIs503:
    """ASGI middleware: a request cancelled before its response started (uvicorn cancels
    what is still running when the graceful shutdown times out, and then answers 500) is
    answered 503 with ``Retry-After`` and the connection closed."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        started = False

        async def tracking(message: Message) -> None:
            nonlocal started
            if message.get("type") == "http.response.start":
                started = True
            await send(message)

        try:
            await self.app(scope, receive, tracking)
        except asyncio.CancelledError:
            if not started:
                body = json.dumps({"detail": SHUTTING_DOWN}).encode()
                headers: list[tuple[bytes, bytes]] = [
                    (b"content-type", b"application/json"),
                    (b"content-length", str(len(body)).encode()),
                    (b"retry-after", str(SHUTDOWN_RETRY_S).encode()),
                    (b"connection", b"close"),
                ]
                with contextlib.suppress(Exception):
                    await send({"type": "http.response.start", "status": 503, "headers": headers})
                    await send({"type": "http.response.body", "body": body})
            raise


class PerMinute:
    """At most ``per_min`` writes of one kind a minute from all network clients together (a
    token bucket of
    ``per_min`` tokens refilled over a minute), so a loop of them cannot fill the disk at the
    rate the daemon can write; a further one is a 429 with ``Retry-After``.

    Parameters
    ----------
    what : str
        What is counted, for the message (``campaigns``).
    setting : str
        The ``[requests]`` setting that says how many, for the message.
    per_min : int
        0: no limit.
    """

    def __init__(self, what: str, setting: str, per_min: int) -> None:
        self.what, self.setting, self.per_min = what, setting, per_min
        self.bucket = TokenBuckets(per_min / 60.0, max(per_min, 1))

    def take(self, request: Request) -> None:
        """Count one, or raise the 429 naming the limit. A request without a network peer
        (an in-process client: :func:`daemon.api.http.guard.peer_key`) is not counted, as the
        per-peer rate does not count it."""
        if peer_key(request.scope) is None:
            return
        wait_s = self.bucket.take("all")
        if wait_s > 0.0:
            raise HTTPException(
                429,
                f"{self.what}: at most {self.per_min} a minute ([requests] {self.setting}); "
                f"retry in {retry_after(wait_s)} s",
                headers={"Retry-After": retry_after(wait_s)},
            )


def per_minute_of(settings: Any) -> dict[str, PerMinute]:
    """The per-minute limits of the ``[requests]`` settings: ``campaign`` and ``import``."""
    r = settings.requests
    return {
        "campaign": PerMinute("campaigns", "campaigns_per_min", r.campaigns_per_min),
        "import": PerMinute("CSV imports", "imports_per_min", r.imports_per_min),
    }


def gates_of(settings: Any) -> dict[str, WorkGate]:
    """The gates of the ``[requests]`` settings: ``filter`` and ``check``."""
    r = settings.requests
    return {
        "filter": WorkGate(
            "program filters",
            r.max_filters,
            r.max_queued_filters,
            r.retry_after_s,
            r.queue_timeout_s,
        ),
        "check": WorkGate(
            "identification checks, imports, exports and compensations",
            r.max_checks,
            r.max_queued_checks,
            r.retry_after_s,
            r.queue_timeout_s,
        ),
    }
