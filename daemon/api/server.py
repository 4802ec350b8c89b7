"""The HTTP server's bounds against slow and many clients (uvicorn + h11), used by
``cablecal serve``.

A client that opens connections and sends a request slowly, or not at all, holds a socket
and a file descriptor each. Three bounds, each at the layer that sees it:

- **Request head**: :class:`BoundedH11Protocol` closes a connection whose request line and
  headers are not complete :data:`HEAD_TIMEOUT_S` after it opened or after its previous
  response (uvicorn itself has no such timeout; its keep-alive timer stops at the first byte).
- **Request body**: :class:`daemon.api.guard.RequestGuard` answers 408 when a started body
  stalls for :data:`daemon.api.guard.BODY_GAP_TIMEOUT_S` or is not complete within
  :data:`daemon.api.guard.BODY_TIMEOUT_S`.
- **Connections**: at most :data:`MAX_CONNECTIONS` at once (uvicorn's ``limit_concurrency``:
  a request beyond it gets 503 at once), and idle keep-alive connections close after
  :data:`KEEP_ALIVE_S`.

So held-open connections are dropped within seconds and never crowd out ``/health``.
"""

from __future__ import annotations

import asyncio
from typing import Any, Final

from uvicorn.protocols.http.h11_impl import H11Protocol

#: Time for a request line and headers to arrive, from the connection's start or its previous
#: response [s].
HEAD_TIMEOUT_S: Final = 10.0
#: Idle time after a response before a keep-alive connection is closed [s].
KEEP_ALIVE_S: Final = 5
#: Connections and requests in progress at once; further requests get 503.
MAX_CONNECTIONS: Final = 512
#: Largest request head h11 buffers [bytes] (h11's default, stated here so it has one home).
MAX_HEAD_BYTES: Final = 16 * 1024


class BoundedH11Protocol(H11Protocol):
    """uvicorn's h11 protocol with a deadline for each request head (see the module)."""

    head_timeout_s: float = HEAD_TIMEOUT_S

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        super().connection_made(transport)
        self._head_timer: asyncio.TimerHandle | None = None
        self._arm_head_timer()

    def on_response_complete(self) -> None:
        super().on_response_complete()
        self._arm_head_timer()

    def connection_lost(self, exc: Exception | None) -> None:
        self._cancel_head_timer()
        super().connection_lost(exc)

    def _arm_head_timer(self) -> None:
        self._cancel_head_timer()
        if not self.transport.is_closing():
            self._head_timer = self.loop.call_later(self.head_timeout_s, self._head_timeout)

    def _cancel_head_timer(self) -> None:
        timer = getattr(self, "_head_timer", None)
        if timer is not None:
            timer.cancel()
            self._head_timer = None

    def _head_timeout(self) -> None:
        """No request in progress (its head never completed): close the connection."""
        self._head_timer = None
        if self.cycle is None or self.cycle.response_complete:
            self.transport.close()


def uvicorn_options() -> dict[str, Any]:
    """The bounds above as ``uvicorn.Config`` keyword arguments."""
    return {
        "http": BoundedH11Protocol,
        "timeout_keep_alive": KEEP_ALIVE_S,
        "limit_concurrency": MAX_CONNECTIONS,
        "h11_max_incomplete_event_size": MAX_HEAD_BYTES,
    }
