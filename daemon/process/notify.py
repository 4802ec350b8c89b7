"""systemd notify protocol (``sd_notify``), spoken over the socket directly.

Under ``Type=notify`` systemd passes the path of a datagram socket in ``NOTIFY_SOCKET``; the
service sends newline-separated ``KEY=VALUE`` assignments to it:

- ``READY=1`` once startup is complete (the store is open and the API listens);
- ``STATUS=...`` a one-line human summary, shown by ``systemctl status cablecal``;
- ``WATCHDOG=1`` keep-alive pings, at least every ``WatchdogSec=`` (systemd passes it as
  ``WATCHDOG_USEC``, and the main PID as ``WATCHDOG_PID``); when pings stop, systemd kills
  the service with SIGABRT and ``Restart=on-failure`` starts it again;
- ``STOPPING=1`` and ``RELOADING=1`` around shutdown and reloads.

The address is a filesystem path, or an abstract socket name written with a leading ``@``.
Outside systemd ``NOTIFY_SOCKET`` is unset and every call is a no-op, so the daemon runs the
same in a terminal, in tests and under systemd. Sending never raises: a lost notification is
logged, and a daemon that cannot reach systemd keeps serving (if its pings do not arrive,
systemd restarts it, which is the right outcome).

Where the pings come from
-------------------------
:func:`watchdog_loop` must run as a task **on the main event loop** (the uvicorn loop, the one
the API and the sampler run on). A ping is then proof that this loop still turns: if a
callback blocks it (a hung serial read done synchronously, a deadlock, a CPU-bound job run on
the loop by mistake), the pings stop and systemd restarts the daemon. Never ping from a side
thread or a timer thread: such a thread keeps pinging while the loop is dead, and the watchdog
no longer watches anything.
"""

from __future__ import annotations

import asyncio
import logging
import os
import socket
import time
from collections.abc import Callable, Mapping

logger = logging.getLogger(__name__)

#: Tick period when systemd set no watchdog but a status callback is given [s].
STATUS_ONLY_INTERVAL_S = 10.0
#: A watchdog tick this late (or a whole period late, if shorter) means the event loop was
#: blocked; it is logged [s].
LOOP_LAG_WARN_S = 1.0


def _parse_address(notify_socket: str) -> str | bytes:
    """``NOTIFY_SOCKET`` → address for ``sendto``: a path, or ``b"\\0name"`` for ``@name``."""
    if notify_socket.startswith("@"):
        return b"\0" + notify_socket[1:].encode()
    return notify_socket


class Notifier:
    """Sends sd_notify messages to systemd; every method is a no-op without a socket.

    Parameters
    ----------
    notify_socket : str or None
        The ``NOTIFY_SOCKET`` value: a filesystem path or ``@abstract-name``. None disables
        all notifications.
    watchdog_usec : int or None
        ``WATCHDOG_USEC``: the watchdog timeout [µs]; None when systemd runs no watchdog for
        this process.

    Attributes
    ----------
    watchdog_interval_s : float or None
        Ping period [s]: half the watchdog timeout, as systemd recommends, or None.
    """

    def __init__(self, notify_socket: str | None, watchdog_usec: int | None = None) -> None:
        if notify_socket is not None and notify_socket in ("", "@"):
            raise ValueError(f"notify_socket: expected a path or '@name', got {notify_socket!r}")
        if watchdog_usec is not None and watchdog_usec <= 0:
            raise ValueError(f"watchdog_usec: expected > 0, got {watchdog_usec}")
        self.notify_socket = notify_socket
        self.watchdog_interval_s: float | None = (
            watchdog_usec / 2e6 if watchdog_usec is not None and notify_socket else None
        )
        self._address = _parse_address(notify_socket) if notify_socket else None
        self._sock: socket.socket | None = None
        self._failing = False

    @classmethod
    def from_env(cls, environ: Mapping[str, str] | None = None) -> Notifier:
        """Read ``NOTIFY_SOCKET``, ``WATCHDOG_USEC`` and ``WATCHDOG_PID`` (default: os.environ).

        The watchdog is ignored when ``WATCHDOG_PID`` names another process (the variables
        were inherited from a parent) or when ``WATCHDOG_USEC`` is not a positive integer.
        """
        env = os.environ if environ is None else environ
        notify_socket = env.get("NOTIFY_SOCKET") or None
        if notify_socket == "@":
            logger.warning("NOTIFY_SOCKET=%r is not a socket address; notifications off", "@")
            notify_socket = None
        watchdog_usec: int | None = None
        raw_usec = env.get("WATCHDOG_USEC")
        if raw_usec:
            try:
                watchdog_usec = int(raw_usec)
            except ValueError:
                logger.warning("WATCHDOG_USEC=%r is not an integer; watchdog off", raw_usec)
            else:
                if watchdog_usec <= 0:
                    watchdog_usec = None
        raw_pid = env.get("WATCHDOG_PID")
        if watchdog_usec is not None and raw_pid:
            try:
                for_us = int(raw_pid) == os.getpid()
            except ValueError:
                for_us = False
            if not for_us:
                logger.info("WATCHDOG_PID=%s is not this process; watchdog off", raw_pid)
                watchdog_usec = None
        return cls(notify_socket, watchdog_usec)

    @property
    def enabled(self) -> bool:
        """True when a notify socket is configured."""
        return self._address is not None

    def notify(self, message: str) -> bool:
        """Send one datagram of ``KEY=VALUE`` lines. Returns True if it was sent.

        Never blocks (the socket is non-blocking) and never raises: errors are logged, at
        WARNING for the first of a run of failures, then at DEBUG until a send succeeds.
        """
        if self._address is None:
            return False
        try:
            if self._sock is None:
                sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
                sock.setblocking(False)
                self._sock = sock
            self._sock.sendto(message.encode(), self._address)
        except OSError as exc:
            level = logging.DEBUG if self._failing else logging.WARNING
            logger.log(
                level,
                "sd_notify to %s failed: %s",
                self.notify_socket,
                exc,
                extra={"error": type(exc).__name__},
            )
            self._failing = True
            return False
        if self._failing:
            logger.info("sd_notify to %s works again", self.notify_socket)
            self._failing = False
        return True

    def ready(self, status: str | None = None) -> bool:
        """``READY=1`` (with an optional ``STATUS=``): startup is complete."""
        return self.notify("READY=1" + (f"\nSTATUS={_one_line(status)}" if status else ""))

    def status(self, text: str) -> bool:
        """``STATUS=text``: shown by ``systemctl status``; newlines are replaced by spaces."""
        return self.notify(f"STATUS={_one_line(text)}")

    def watchdog(self) -> bool:
        """``WATCHDOG=1``: keep-alive ping. Call it only from the main event loop."""
        return self.notify("WATCHDOG=1")

    def stopping(self) -> bool:
        """``STOPPING=1``: shutdown has begun."""
        return self.notify("STOPPING=1")

    def reloading(self) -> bool:
        """``RELOADING=1`` with ``MONOTONIC_USEC`` (required by ``Type=notify-reload``);
        send :meth:`ready` when the reload is done."""
        now_usec = time.clock_gettime_ns(time.CLOCK_MONOTONIC) // 1000
        return self.notify(f"RELOADING=1\nMONOTONIC_USEC={now_usec}")

    def extend_timeout(self, seconds: float) -> bool:
        """``EXTEND_TIMEOUT_USEC``: ask for ``seconds`` more to start or stop (a long migration)."""
        return self.notify(f"EXTEND_TIMEOUT_USEC={round(seconds * 1e6)}")

    def close(self) -> None:
        """Close the socket; a later call opens a new one."""
        if self._sock is not None:
            self._sock.close()
            self._sock = None


def _one_line(text: str) -> str:
    return " ".join(text.splitlines()).strip()


async def watchdog_loop(
    notifier: Notifier,
    health: Callable[[], str | None] | None = None,
    *,
    status_interval_s: float = STATUS_ONLY_INTERVAL_S,
) -> None:
    """Ping the watchdog and publish ``health()`` as STATUS, from the main event loop.

    Run it as a task on the loop whose liveness the watchdog should prove (the uvicorn loop;
    see the module docstring): ``asyncio.create_task(watchdog_loop(notifier, health))`` in the
    lifespan, cancelled on shutdown. A blocked loop stops the pings, which is the point.

    Parameters
    ----------
    notifier : Notifier
        Returns at once if it is not :attr:`~Notifier.enabled`.
    health : callable, optional
        Called on every tick, on the loop, so it must be quick and must not block. Returns
        the STATUS text (sent only when it changes) or None to leave the status as it is. If
        it raises, the error is logged and the ping is still sent: the ping proves the loop
        turns; health problems belong in STATUS, the API and the metrics.
    status_interval_s : float
        Tick period when systemd runs no watchdog (only STATUS is sent) [s].
    """
    if status_interval_s <= 0:
        raise ValueError(f"status_interval_s: expected > 0, got {status_interval_s}")
    if not notifier.enabled:
        return
    ping = notifier.watchdog_interval_s is not None
    if not ping and health is None:
        return
    interval_s = notifier.watchdog_interval_s or status_interval_s
    lag_warn_s = min(LOOP_LAG_WARN_S, interval_s)
    last_status: str | None = None
    loop = asyncio.get_running_loop()
    due = loop.time()
    while True:
        late_s = loop.time() - due
        if late_s > lag_warn_s:
            logger.warning("event loop was blocked: watchdog tick %.1f s late", late_s)
        lines = ["WATCHDOG=1"] if ping else []
        status: str | None = None
        if health is not None:
            try:
                text = health()
            except Exception:
                logger.exception("health callback of the watchdog loop failed")
                text = None
            if text is not None and _one_line(text) != last_status:
                status = _one_line(text)
                lines.append(f"STATUS={status}")
        if lines and notifier.notify("\n".join(lines)) and status is not None:
            last_status = status
        due = loop.time() + interval_s
        await asyncio.sleep(interval_s)
