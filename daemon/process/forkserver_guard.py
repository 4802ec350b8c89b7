"""Imported only in the job pool's forkserver (``set_forkserver_preload``): starts
:func:`daemon.process.workers.guard_forkserver`, which kills and reaps the pool's children when the
daemon dies. Never import it in the daemon itself: the guard would watch the daemon's parent."""

from daemon.process.workers import guard_forkserver

GUARD = guard_forkserver()
