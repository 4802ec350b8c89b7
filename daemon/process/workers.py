"""Set-up of the daemon's child processes: they die with the daemon, yield the CPU to it, and
use one BLAS thread each.

:func:`init_child` is the initializer of the identification pool's workers and of the
multiprocessing manager (:class:`daemon.jobs.manager.JobManager`). It runs first thing in each
child.

Dying with the daemon
---------------------
The pool uses the ``forkserver`` start method, so its workers and the manager are forked by the
forkserver process, not by the daemon, and each of them gets a copy of the write end of the
forkserver's "alive" pipe: the forkserver exits only once the daemon *and* every one of its
children are gone. ``prctl(PR_SET_PDEATHSIG)`` in a worker fires when the thread that forked
it dies, which is the forkserver's, so after a SIGKILL of the daemon it would never fire: the
workers keep the forkserver alive and the forkserver keeps no-one from running. (Under the
``spawn`` method the forking thread would be whichever daemon thread submitted first, which
may exit long before the daemon.)

So each child watches the daemon itself: a thread blocks on the daemon's sentinel,
``multiprocessing.parent_process().sentinel``, the read end of a pipe whose write end only the
daemon holds. The kernel closes it when the daemon dies, however it dies (SIGKILL, OOM killer,
crash); the read end then reports EOF and the thread ends the process with :func:`os._exit`
(whatever the main thread is computing: ``_exit`` stops every thread).

The forkserver watches the daemon too (:func:`guard_forkserver`, started by the preloaded
:mod:`daemon.process.forkserver_guard`): when the daemon dies it ignores ``SIGCHLD`` (so the kernel
reaps each child as it exits, whatever the forkserver's threads are doing), SIGKILLs its
children and exits. The children are reaped by their living parent and none is left a zombie
for pid 1, which in a container may reap late; only the forkserver itself is left to pid 1, as
the daemon is to its own parent. A child whose forkserver has no guard (a plain pool with
:func:`init_child`) waits :data:`FORKSERVER_GRACE_S`, then SIGKILLs the forkserver, its
parent, which serves only the dead daemon: left alone it would exit by itself once the
children are gone, but only after tearing down an interpreter with numpy and scipy loaded
(bench/design_figures.md). The pid is the one recorded at start and is signalled only while
it is still this process's parent, so it cannot have been reused. Then the multiprocessing
resource tracker, whose pipe they all held, sees EOF and exits. It works on any POSIX system
(the child scan of the guard reads Linux's /proc; elsewhere the children exit by their own
watch).

Priority
--------
The sampler's poll loop runs in the daemon's event loop and must keep its rate while an
identification runs on the same (small) machine. The children add ``nice`` to their niceness
(at ``nice`` 10 the kernel's fair scheduler weighs the daemon about nine times a child).
Niceness alone is not enough where the kernel groups tasks by session (``sched_autogroup``, on
by default on desktop kernels and for processes outside a cpu cgroup): it weighs only tasks
within one group, and a busy worker in the daemon's group keeps that group always runnable, so
the daemon loses the prompt wake-up a sleeping group gets and waits behind every other busy
session (the poll rate fell while a job ran, with ``nice`` 10 alone: bench/design_figures.md).
So a child with ``nice`` > 0 also starts a session of its own (``setsid``: its own autogroup)
and gives that group the same ``nice`` (``/proc/self/autogroup``); under systemd, where the
service's cgroup replaces the autogroup, ``nice`` does the work. The children also limit
BLAS/OpenMP to ``blas_threads`` threads (threadpoolctl, for the libraries the forkserver
preloaded; the environment variables, for any loaded later), so a job never occupies more cores
than the pool has workers. A system that forbids raising the niceness (a seccomp filter without
``setpriority``, such as systemd's ``SystemCallFilter=~@resources``) gets a warning, not a
failure.
"""

from __future__ import annotations

import contextlib
import logging
import multiprocessing
import multiprocessing.connection
import os
import signal
import threading
import time
from pathlib import Path
from typing import Any

from daemon.process.blas import BLAS_THREAD_VARIABLES

log = logging.getLogger("cablecal.workers")

#: Exit status of a child that saw the daemon die.
EXIT_PARENT_GONE = 70

#: Environment variables that size the thread pools of BLAS and OpenMP libraries.
THREAD_ENV = BLAS_THREAD_VARIABLES

#: How long a child whose daemon died leaves the forkserver's guard to kill and reap it before
#: it kills the forkserver and exits by itself [s].
FORKSERVER_GRACE_S = 0.5
#: How long the forkserver's guard waits for its killed children [s].
REAP_TIMEOUT_S = 1.0

_limits: Any = None  # keeps the threadpoolctl limiter of this process alive


def watch_parent() -> threading.Thread | None:
    """Start a daemon thread that ends this process as soon as its multiprocessing parent
    dies; None in a process without one (the main process)."""
    parent = multiprocessing.parent_process()
    if parent is None or parent.sentinel is None:
        return None
    sentinel = parent.sentinel
    # Forked by a forkserver: the parent process is not the multiprocessing parent.
    forkserver = os.getppid() if os.getppid() != parent.pid else None

    def wait_for_parent() -> None:
        multiprocessing.connection.wait([sentinel])
        if forkserver is not None:
            # The forkserver's own guard (:func:`guard_forkserver`) kills and reaps this
            # process in the meantime; only if it is not there does the child act alone.
            time.sleep(FORKSERVER_GRACE_S)
            if os.getppid() == forkserver:
                with contextlib.suppress(OSError):
                    os.kill(forkserver, signal.SIGKILL)
        os._exit(EXIT_PARENT_GONE)

    thread = threading.Thread(target=wait_for_parent, name="cablecal-parent-watch", daemon=True)
    thread.start()
    return thread


def _children() -> list[int]:
    """Pids of this process's children (Linux /proc; empty elsewhere)."""
    me, found = os.getpid(), []
    with contextlib.suppress(OSError):
        for entry in os.listdir("/proc"):
            if not entry.isdigit():
                continue
            try:
                stat = Path(f"/proc/{entry}/stat").read_text()
            except OSError:
                continue
            if int(stat.rsplit(")", 1)[1].split()[1]) == me:
                found.append(int(entry))
    return found


def _ignore_sigchld() -> bool:
    """``SIGCHLD`` to ``SIG_IGN`` from any thread (libc ``signal``; Python's
    :func:`signal.signal` only works in the main thread): from now on the kernel reaps this
    process's children as they exit, whatever its threads are doing. True if set."""
    import ctypes

    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.signal.restype = ctypes.c_void_p
        libc.signal.argtypes = [ctypes.c_int, ctypes.c_void_p]
        previous = libc.signal(int(signal.SIGCHLD), 1)  # SIG_IGN = 1
        return bool(previous != ctypes.c_void_p(-1).value)  # SIG_ERR = -1
    except (OSError, AttributeError):
        return False


def reap_children(pids: list[int], timeout_s: float = REAP_TIMEOUT_S) -> list[int]:
    """SIGKILL ``pids`` (children of this process) so that none is left a zombie: first
    ``SIGCHLD`` is ignored, so the kernel reaps each as it dies (a wait in this thread could
    be stopped half-way: the forkserver's main thread starts its interpreter's teardown as
    soon as the last child is gone, and a daemon thread then never gets the GIL back); those
    already dead are reaped here. Returns those still present after ``timeout_s`` [s]."""
    _ignore_sigchld()
    for pid in pids:
        with contextlib.suppress(OSError):
            os.kill(pid, signal.SIGKILL)
        with contextlib.suppress(ChildProcessError):
            os.waitpid(pid, os.WNOHANG)  # a zombie from before SIGCHLD was ignored
    left, deadline = list(pids), time.monotonic() + timeout_s
    while left and time.monotonic() < deadline:
        left = [p for p in left if Path(f"/proc/{p}").exists()]
        if left:
            time.sleep(0.01)
    return left


def guard_forkserver() -> threading.Thread | None:
    """In the forkserver (run by the import of :mod:`daemon.process.forkserver_guard`, which the job
    manager preloads there): when the daemon dies, SIGKILL every child (pool workers, the
    manager) and reap them, then exit. The children are reaped by their own, living parent,
    so none stays a zombie waiting for init (a container's pid 1 may reap late); only the
    forkserver itself is left to init, as the daemon is to its own parent. None when this
    process's parent is already init (the daemon died before the guard started)."""
    daemon_pid = os.getppid()
    if daemon_pid <= 1:
        return None

    def wait_for_daemon() -> None:
        try:
            fd = os.pidfd_open(daemon_pid)  # Linux >= 5.3: readable once the daemon exits
        except (AttributeError, OSError):
            fd = None
        if fd is not None:
            multiprocessing.connection.wait([fd])
        else:
            while os.getppid() == daemon_pid:
                time.sleep(0.1)
        reap_children(_children())
        os._exit(EXIT_PARENT_GONE)

    # Not a daemon thread: when the children are gone the forkserver's main thread exits, and
    # its interpreter then waits for this thread (before the slow teardown of numpy and
    # scipy) instead of freezing it half-way.
    thread = threading.Thread(target=wait_for_daemon, name="cablecal-forkserver-guard")
    thread.start()
    return thread


def lower_priority(nice: int) -> int:
    """Add ``nice`` (>= 0) to this process's niceness; returns the niceness now.

    Refused by the system (EPERM): a warning, and the niceness stays."""
    if nice < 0:
        raise ValueError(f"nice: must be >= 0, got {nice}")
    try:
        return os.nice(nice)
    except OSError as exc:
        log.warning("cannot lower the priority of worker %d by %d: %s", os.getpid(), nice, exc)
        return os.nice(0)


def own_sched_group(nice: int) -> bool:
    """Start a session of its own (so a scheduling autogroup of its own) and set that group's
    ``nice``; True if the process now runs in its own session. Not possible (already a group
    leader, no autogroup support): the process stays where it is."""
    try:
        os.setsid()
    except OSError as exc:
        log.warning("worker %d cannot start its own session: %s", os.getpid(), exc)
        return False
    path = Path("/proc/self/autogroup")
    if not path.exists():
        return True
    for _ in range(10):  # unprivileged writes are rate-limited system-wide (EAGAIN)
        try:
            path.write_text(f"{nice}\n")
            return True
        except BlockingIOError:
            time.sleep(0.11)
        except OSError as exc:
            log.warning("worker %d cannot set its autogroup nice %d: %s", os.getpid(), nice, exc)
            return True
    log.warning("worker %d: autogroup nice %d not set (busy)", os.getpid(), nice)
    return True


def limit_threads(blas_threads: int) -> None:
    """Use at most ``blas_threads`` (>= 1) threads in BLAS and OpenMP in this process."""
    global _limits
    if blas_threads < 1:
        raise ValueError(f"blas_threads: must be >= 1, got {blas_threads}")
    for name in THREAD_ENV:
        os.environ[name] = str(blas_threads)
    from threadpoolctl import threadpool_limits  # type: ignore[import-untyped]

    _limits = threadpool_limits(limits=blas_threads)


def init_child(nice: int, blas_threads: int) -> None:
    """Initializer of a pool worker or the manager: watch the daemon, lower the priority by
    ``nice`` (and, if ``nice`` > 0, in a scheduling group of its own), cap BLAS/OpenMP at
    ``blas_threads`` threads."""
    watch_parent()
    lower_priority(nice)
    if nice > 0:
        own_sched_group(nice)
    limit_threads(blas_threads)


def child_state() -> dict[str, Any]:
    """This process's pid, niceness and BLAS/OpenMP thread counts (for tests and the bench)."""
    from threadpoolctl import threadpool_info

    return {
        "pid": os.getpid(),
        "nice": os.nice(0),
        "session": os.getsid(0),
        "threads": {str(i.get("internal_api")): int(i["num_threads"]) for i in threadpool_info()},
        "watchdog": any(t.name == "cablecal-parent-watch" for t in threading.enumerate()),
    }


class ChildFailed(RuntimeError):
    """The work of :func:`run_in_child` raised something that is not an answer to the client
    (a bug, or memory exhausted); the message names its type."""


def _child_main(conn: Any, fn: Any, args: tuple[Any, ...], nice: int, blas_threads: int) -> None:
    """Body of a :func:`run_in_child` process: the set-up of :func:`init_child`, then
    ``fn(*args)``; sends ``("ok", value)``, ``("raise", exception)`` for an exception that
    pickles (an HTTP error of the request), else ``("error", message)``."""
    import pickle

    init_child(nice, blas_threads)
    try:
        reply: tuple[str, Any] = ("ok", fn(*args))
    except BaseException as exc:  # the daemon decides; this process only reports
        try:
            pickle.loads(pickle.dumps(exc))
            reply = ("raise", exc)
        except Exception:
            reply = ("error", f"{type(exc).__name__}: {exc}")
    try:
        conn.send(reply)
    except Exception as exc:  # a result that cannot be pickled or is too large
        conn.send(("error", f"{type(exc).__name__}: {exc}"))
    conn.close()


async def run_in_child(fn: Any, *args: Any, nice: int = 10, blas_threads: int = 1) -> Any:
    """``fn(*args)`` in a process of its own, forked by the ``forkserver`` (the one of the
    identification pool, with its preloaded modules), set up as :func:`init_child` (dies with
    the daemon, ``nice``, BLAS threads): the daemon's event loop, which polls the indicator,
    neither waits for the work nor shares its GIL, and the memory the work used is returned
    to the system when it ends. ``fn`` must be importable by name (a module-level function).

    Cancelled (the client left, shutdown): the process is killed at once (SIGKILL) and
    reaped, and the cancel is raised on.

    Raises
    ------
    Exception
        What ``fn`` raised, when it pickles (e.g. an HTTP error naming the field).
    ChildFailed
        Anything else: an exception that does not pickle, or the process died (killed, out of
        memory).
    """
    import asyncio

    ctx = multiprocessing.get_context("forkserver")
    receiver, sender = ctx.Pipe(duplex=False)
    proc = ctx.Process(
        target=_child_main, args=(sender, fn, args, nice, blas_threads), name="cablecal-work"
    )
    # Started (which pickles the arguments) and waited for in a worker thread.
    work = asyncio.ensure_future(asyncio.to_thread(_start_and_receive, proc, sender, receiver))
    try:
        kind, value = await asyncio.shield(work)
    except asyncio.CancelledError:
        while not work.done():  # kill it (once started); the thread then reads EOF and ends
            if proc.pid is not None and proc.exitcode is None:
                proc.kill()
            await asyncio.wait({work}, timeout=0.05)
        raise
    finally:
        if proc.pid is not None:
            await asyncio.to_thread(proc.join, REAP_TIMEOUT_S)
    if kind == "ok":
        return value
    if kind == "raise":
        raise value
    raise ChildFailed(str(value))


def _start_and_receive(proc: Any, sender: Any, receiver: Any) -> tuple[str, Any]:
    """Start ``proc`` and wait for its reply (in a worker thread, not the event loop)."""
    try:
        proc.start()
        sender.close()  # the child holds the only write end: its death is an EOF here
        reply: tuple[str, Any] = receiver.recv()
        return reply
    except EOFError:
        proc.join(REAP_TIMEOUT_S)
        return "error", f"the worker process died (exit status {proc.exitcode})"
    finally:
        sender.close()
        receiver.close()
