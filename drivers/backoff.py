"""Exponential back-off between reconnect attempts, shared by every driver with a link."""

from __future__ import annotations

import time


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
