"""Exponential back-off between reconnect attempts, shared by every driver with a link."""

from __future__ import annotations

import time
from typing import Literal


class ReconnectBackoff:
    """When the next reconnect may be tried.

    After each failed attempt the delay doubles, from ``min_s`` up to ``max_s``; a success
    resets it. All times are :func:`time.monotonic` seconds.
    """

    def __init__(self, min_s: float, max_s: float) -> None:
        self.min_s = min_s
        self.max_s = max_s
        self.delay_s = 0.0
        self.next_attempt = 0.0

    def remaining_s(self, now: float) -> float:
        """Seconds until the next attempt is allowed (0 when it is)."""
        return max(self.next_attempt - now, 0.0)

    def failed(self) -> None:
        """An attempt failed: double the delay (within ``min_s``..``max_s``)."""
        self.delay_s = min(max(2 * self.delay_s, self.min_s), self.max_s)
        self.defer(self.delay_s)

    def succeeded(self) -> None:
        """Connected: the next failure starts again from ``min_s``."""
        self.delay_s = 0.0

    def dropped(self) -> None:
        """An open link was lost: wait ``min_s`` before reconnecting."""
        self.delay_s = self.min_s
        self.defer(self.min_s)

    def defer(self, seconds: float) -> None:
        """No attempt before ``seconds`` from now."""
        self.next_attempt = time.monotonic() + seconds


class SilentAttempts:
    """Retry policy of a request/reply link whose peer may stay silent (a dropped reply).

    A silent attempt is retried at once on the same connection, up to ``retries`` times per
    request; only after ``reconnect_after`` silent attempts in a row (counted across
    requests, reset by any reply) is the connection deemed dead and to be re-opened (with
    :class:`ReconnectBackoff`). A single dropped reply therefore costs one short timeout,
    not a reconnect.

    Per-attempt reply timeouts: every attempt but the last waits ``fast_timeout_s``, the
    last ``last_timeout_s`` (≥ the fast one). On loopback or a LAN a reply takes
    milliseconds, so short waits bound the stall of dropped replies: one drop costs
    ``fast_timeout_s``, two in a row ``2 * fast_timeout_s``. Both must stay below the
    sampler's ``stale_s`` (0.5 s), or the stall breaks the settle window it falls into; on a
    lossy link two drops in a row are common (the read rates with dropped replies:
    bench/robot_link.md), and an earlier draft that waited a full second from the first retry
    on made auto capture lose poses. The long last wait still reads a controller that is
    alive but slow (busy), instead of declaring it down after a string of short waits.
    """

    def __init__(
        self, retries: int, reconnect_after: int, fast_timeout_s: float, last_timeout_s: float
    ) -> None:
        if retries < 0:
            raise ValueError(f"retries: must be >= 0, got {retries}")
        if reconnect_after < 1:
            raise ValueError(f"reconnect_after: must be >= 1, got {reconnect_after}")
        if not fast_timeout_s > 0:  # also rejects NaN
            raise ValueError(f"fast_timeout_s: must be > 0, got {fast_timeout_s}")
        self.retries = retries
        self.reconnect_after = reconnect_after
        self.fast_timeout_s = fast_timeout_s
        self.last_timeout_s = max(last_timeout_s, fast_timeout_s)
        self.in_row = 0
        #: Totals since creation [count]: attempts that got no reply, and retries that did.
        self.silent_total = 0
        self.recovered_total = 0

    def timeouts_s(self) -> list[float]:
        """Reply timeout of each attempt of one request [s]: ``1 + retries`` entries."""
        return [self.fast_timeout_s] * self.retries + [self.last_timeout_s]

    def silent(self, attempt: int) -> Literal["retry", "reopen", "fail"]:
        """Attempt number ``attempt`` (0 = first) got no reply. What to do: ``"retry"`` at
        once on the same connection; ``"reopen"``: it was the ``reconnect_after``-th silent
        attempt in a row, close the connection and fail the request; ``"fail"``: no retry
        left."""
        self.in_row += 1
        self.silent_total += 1
        if self.in_row >= self.reconnect_after:
            return "reopen"
        return "retry" if attempt < self.retries else "fail"

    def failure_text(self, attempt: int) -> str:
        """``"no reply to 3 attempt(s) (waited 0.2, 1, 1 s)"`` after attempt ``attempt``."""
        waits = ", ".join(f"{t:g}" for t in self.timeouts_s()[: attempt + 1])
        return f"no reply to {attempt + 1} attempt(s) (waited {waits} s)"

    def replied(self, attempt: int) -> None:
        """Attempt number ``attempt`` (0 = first) got its reply."""
        self.in_row = 0
        if attempt:
            self.recovered_total += 1

    def reset(self) -> None:
        """The connection was (re-)opened."""
        self.in_row = 0
