"""Identification jobs: run :func:`calib.identify.identify` in a process pool, off the event loop.

Design
------
* The pool is a :class:`~concurrent.futures.ProcessPoolExecutor` on the ``forkserver`` context
  (the daemon has threads, so plain ``fork`` is unsafe), with ``calib.identify`` preloaded so a
  job starts without re-importing numpy and scipy.
* Every child (the workers and the manager) runs :func:`daemon.process.workers.init_child`: it exits
  within moments of the daemon's death, even a SIGKILL, and runs at a lower priority with
  ``worker_blas_threads`` BLAS threads, so the sampler keeps its poll rate during a job.
* A job gets a snapshot of the campaign's included samples at submission time, as plain lists
  (no precision lost), the nominal model as a mapping, and the options as a mapping.
* Progress comes back through a manager queue as numbers (fraction, the fit's whole
  ``iteration`` and its data RMS ``cost_rms_mm`` [mm]: see
  :class:`~calib.solvers.common.ProgressFn`); a thread takes it and commits the newest of each
  job at most every ``PROGRESS_STORE_INTERVAL_S``, and a succeeded job's result is committed in
  a thread too: the event loop, which also runs the sampler, never waits for those fsyncs.
  Cancellation goes out through a manager dict the worker's progress callback polls, raising
  :class:`calib.solvers.common.Cancelled`. A queued job is cancelled by cancelling its future.
* A robot has one current calibration (``robots.current_identification_id``). A robot's first
  plausible result becomes current automatically (``auto_accept``); a later one waits for
  ``POST /identifications/{id}/accept``, so the operator compares old and new first.
* The store holds every state change, so a restart finds each job queued, running or finished;
  :meth:`daemon.store.Store.mark_interrupted` turns the unfinished ones into ``failed``.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import multiprocessing
import queue
import threading
import time
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from multiprocessing.managers import SyncManager
from typing import Any

from calib.options import IdentifyOptions, options_mapping
from calib.result import CalibrationResult
from daemon import metrics
from daemon.config import JobSettings
from daemon.jobs.worker import (
    FINAL_PROGRESS,
    Checked,
    JobsFull,
    Prepared,
    check_job,
    noop,
    prepare_job,
    run_identification,
)
from daemon.process.workers import init_child
from daemon.store import JOB_FINISHED, JobState, StoreNotFound

log = logging.getLogger("cablecal.jobs")

#: Seconds between two commits of progress to the store (the newest message of each job).
PROGRESS_STORE_INTERVAL_S = 0.5
#: The error of a job whose worker process died under it (killed, out of memory).
WORKER_DIED = "the worker process died (killed or out of memory); the job can be started again"


class JobManager:
    """Queue, run, cancel and record identification jobs.

    Parameters
    ----------
    store : daemon.store.Store
    settings : JobSettings
    """

    def __init__(self, store: Any, settings: JobSettings) -> None:
        self.store = store
        self.settings = settings
        self._pool: ProcessPoolExecutor | None = None
        self._manager: Any = None
        self._progress: Any = None
        self._cancel: Any = None
        self._futures: dict[int, Future[dict[str, Any]]] = {}
        self._tasks: dict[int, asyncio.Task[None]] = {}
        self._pump: asyncio.Task[None] | None = None
        # Held while a job's row is read and updated: the progress thread and the event loop.
        self._row_lock = threading.Lock()
        self._stopping = threading.Event()

    @property
    def active(self) -> int:
        """Jobs queued or running in this process."""
        return len(self._tasks)

    async def start(self) -> None:
        """Start the pool and the progress pump; mark jobs of a previous run interrupted."""
        n = self.store.mark_interrupted()
        if n:
            log.warning("%d identification job(s) were interrupted by a restart", n)
        self._stopping.clear()
        ctx = multiprocessing.get_context("forkserver")
        # daemon.process.forkserver_guard: the forkserver kills and reaps its children if we die.
        # The program filter's worker processes (daemon.process.workers.run_in_child) fork from it
        # too.
        ctx.set_forkserver_preload(
            [
                "calib.identify",
                "daemon.jobs.manager",
                "daemon.jobs.worker",
                "daemon.process.forkserver_guard",
                "calib.filter.run",
                "daemon.api.routes.robots.program_filter",
            ]
        )
        child_args = (self.settings.worker_nice, self.settings.worker_blas_threads)
        manager = SyncManager(ctx=ctx)
        manager.start(initializer=init_child, initargs=child_args)
        self._manager = manager
        self._progress = manager.Queue()
        self._cancel = manager.dict()
        self._pool = self._new_pool()
        # Warm the workers up now rather than in the first job.
        await asyncio.wrap_future(self._pool.submit(noop))
        self._pump = asyncio.create_task(self._pump_progress(), name="job-progress")

    def _new_pool(self) -> ProcessPoolExecutor:
        return ProcessPoolExecutor(
            max_workers=self.settings.workers,
            mp_context=multiprocessing.get_context("forkserver"),
            initializer=init_child,
            initargs=(self.settings.worker_nice, self.settings.worker_blas_threads),
        )

    def _renew_broken_pool(self) -> None:
        """A worker that died (SIGKILL, OOM killer) breaks the whole pool: every job in it
        fails (its watcher records why) and the next job gets a new pool. The dead worker is
        reaped by its parent, the forkserver, at once."""
        if self._pool is not None and getattr(self._pool, "_broken", False):
            log.warning("identification pool: a worker died; starting a new pool")
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = self._new_pool()

    async def stop(self) -> None:
        """Cancel running jobs, stop the pool and the manager."""
        self._stopping.set()
        for job_id in list(self._tasks):
            if self._cancel is not None:
                self._cancel[job_id] = True
        if self._pump is not None:
            self._pump.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._pump
        if self._pool is not None:
            self._pool.shutdown(wait=False, cancel_futures=True)
        for task in list(self._tasks.values()):
            task.cancel()
        if self._manager is not None:
            with contextlib.suppress(Exception):
                self._manager.shutdown()

    # ------------------------------------------------------------------ submit / cancel
    def check(self, campaign_id: int, options: IdentifyOptions) -> Checked:
        """:func:`daemon.jobs.worker.check_job` on this daemon's store and settings: what an
        identification of the campaign's included samples would run on, after the one rule
        of what can run. The POST and the readiness route both ask it (in a worker thread,
        or a worker process for a large campaign: :func:`daemon.jobs.worker.prepare_in_child`),
        so what is called ready is what is accepted.

        Raises
        ------
        JobError
            Bad options (the message names the option) or too few samples.
        daemon.store.StoreNotFound
            No such campaign.
        """
        return check_job(self.store, campaign_id, options)

    def prepare(self, campaign_id: int, options: IdentifyOptions) -> Prepared:
        """:meth:`check` and the job's inputs, ready for :meth:`enqueue` (in a worker thread).

        Raises
        ------
        JobError, daemon.store.StoreNotFound
            As :meth:`check`.
        """
        return prepare_job(self.store, campaign_id, options)

    def full(self) -> str | None:
        """Why no further job may be queued (``max_pending`` jobs queued or running), or None."""
        if self.active >= self.settings.max_pending:
            return (
                f"{self.active} identification jobs queued or running, the most [jobs] "
                "max_pending allows; retry once one has finished"
            )
        return None

    def enqueue(self, prepared: Prepared) -> dict[str, Any]:
        """Record a prepared job and queue it in the pool (on the event loop: quick).

        Raises
        ------
        JobsFull
            ``max_pending`` jobs are already queued or running.
        """
        if why := self.full():
            raise JobsFull(why)
        if self._pool is None:
            raise RuntimeError("job manager not started")
        opts = prepared.checked.options
        job = self.store.create_job(
            prepared.campaign_id, prepared.robot_id, opts.method, options_mapping(opts)
        )
        job_id = int(job["id"])
        self._renew_broken_pool()
        model, joints, lengths, anchors, t_s, group = prepared.inputs
        future = self._pool.submit(
            run_identification,
            job_id,
            model,
            joints,
            lengths,
            anchors,
            prepared.checked,
            self._progress,
            self._cancel,
            t_s,
            group,
        )
        self._futures[job_id] = future
        self._tasks[job_id] = asyncio.create_task(
            self._watch(job_id, future, prepared.sample_ids, opts.method)
        )
        return dict(job)

    def cancel(self, job_id: int) -> dict[str, Any]:
        """Cancel a queued or running job (a finished job is returned unchanged)."""
        job = self.store.get_job(job_id)
        if job is None:
            raise StoreNotFound("identification", job_id)
        if job["status"] in JOB_FINISHED:
            return dict(job)
        future = self._futures.get(job_id)
        if future is not None and future.cancel():
            # Never started: the watcher sees CancelledError and records it.
            return dict(self.store.get_job(job_id))
        if self._cancel is not None:
            self._cancel[job_id] = True
        self.store.update_job(job_id, message="cancel requested")
        return dict(self.store.get_job(job_id))

    # ------------------------------------------------------------------ internals
    async def _watch(
        self,
        job_id: int,
        future: Future[dict[str, Any]],
        sample_ids: list[int],
        method: str,
    ) -> None:
        t0 = time.monotonic()
        status = JobState.FAILED
        try:
            # Marked running once a worker picks it up (first progress) or here on start.
            async with asyncio.timeout(self.settings.timeout_s):
                result = await asyncio.wrap_future(future)
        except asyncio.CancelledError:
            status = JobState.CANCELLED
            self._finish(job_id, status, error="cancelled before it started")
            if not future.cancelled():
                raise
        except TimeoutError:
            if self._cancel is not None:
                self._cancel[job_id] = True
            self._finish(job_id, status, error=f"timed out after {self.settings.timeout_s} s")
        except BrokenProcessPool:
            self._finish(job_id, status, error=WORKER_DIED)
            self._renew_broken_pool()
        except Exception as exc:
            from calib.solvers.common import Cancelled

            if isinstance(exc, Cancelled):
                status = JobState.CANCELLED
                self._finish(job_id, status, error="cancelled while running")
            else:
                log.exception("identification job %d failed", job_id, extra={"job_id": job_id})
                self._finish(job_id, status, error=f"{type(exc).__name__}: {exc}")
        else:
            status = JobState.SUCCEEDED
            result = CalibrationResult.from_json(result).with_sample_ids(sample_ids)
            await asyncio.to_thread(self._succeeded, job_id, result, sample_ids)
        finally:
            metrics.JOBS.labels(method, status.value).inc()
            if status is JobState.FAILED:
                metrics.IDENTIFICATIONS_FAILED.inc()
            metrics.JOB_DURATION.labels(method, status.value).observe(time.monotonic() - t0)
            self._futures.pop(job_id, None)
            self._tasks.pop(job_id, None)
            if self._cancel is not None:
                with contextlib.suppress(Exception):
                    self._cancel.pop(job_id, None)

    def _succeeded(
        self, job_id: int, result: dict[str, Any], sample_ids: list[int] | None = None
    ) -> None:
        """Store a succeeded job's result; it becomes the robot's current calibration only
        when it is plausible and the robot has none yet (runs in a thread). With
        ``sample_ids`` (the samples identified), the result says whether they followed the
        campaign's plan (:mod:`daemon.jobs.plan_check`)."""
        iteration, cost = result.pop(FINAL_PROGRESS, None) or (None, None)
        if iteration is not None and cost is not None:
            with self._row_lock:
                self.store.update_job(job_id, iteration=int(iteration), cost_rms_mm=float(cost))
        if sample_ids is not None:
            from daemon.jobs.plan_check import add_plan_check

            job = self.store.get_job(job_id)
            if job is not None:
                try:
                    result = add_plan_check(self.store, int(job["campaign_id"]), sample_ids, result)
                except Exception:  # the check must never lose a result
                    log.exception("plan check of job %d failed", job_id)
        plausible = CalibrationResult.from_json(result).plausible
        robot_id = int(self.store.job(job_id)["robot_id"])
        current = self.store.current_job_id(robot_id)
        accepted = self.settings.auto_accept and plausible and current is None
        self.store.save_result(job_id, result, accepted=accepted)
        if accepted:
            message = "accepted: the robot's first calibration"
        elif not plausible:
            message = "not accepted: parameters implausible"
        elif current is not None:
            message = f"waiting for Accept: compare with the current calibration (job {current})"
        else:
            message = "not accepted automatically"
        self._finish(job_id, JobState.SUCCEEDED, message=message)

    def _finish(
        self, job_id: int, status: JobState, message: str = "", error: str | None = None
    ) -> None:
        fields: dict[str, Any] = {"status": status.value, "finished_at": time.time()}
        if status is JobState.SUCCEEDED:
            fields["progress"] = 1.0
        if message:
            fields["message"] = message
        if error is not None:
            fields["error"] = error
        with self._row_lock:
            self.store.update_job(job_id, **fields)
        log.info("identification job %d %s", job_id, status, extra={"job_id": job_id})

    async def _pump_progress(self) -> None:
        """Move progress messages from the workers into the store (in a thread)."""
        while not self._stopping.is_set():
            try:
                await asyncio.to_thread(self._pump_batch)
            except (EOFError, OSError, BrokenPipeError):
                return

    def _pump_batch(self) -> None:
        """Wait up to 0.5 s for progress, take every message queued, commit the newest of
        each job, then wait ``PROGRESS_STORE_INTERVAL_S`` (runs in a thread)."""
        try:
            first = self._progress.get(True, 0.5)
        except queue.Empty:
            return
        newest = {first[0]: first}
        with contextlib.suppress(queue.Empty):
            while True:
                message = self._progress.get_nowait()
                newest[message[0]] = message
        for job_id, fraction, text, iteration, cost in newest.values():
            self._store_progress(int(job_id), float(fraction), str(text), iteration, cost)
        self._stopping.wait(PROGRESS_STORE_INTERVAL_S)

    def _store_progress(
        self,
        job_id: int,
        fraction: float,
        message: str,
        iteration: int | None,
        cost_rms_mm: float | None,
    ) -> None:
        with self._row_lock:
            if self._stopping.is_set():
                return
            job = self.store.get_job(job_id)
            if job is None or job["status"] in JOB_FINISHED:
                return
            fields: dict[str, Any] = {"progress": min(max(fraction, 0.0), 0.99), "message": message}
            if iteration is not None and cost_rms_mm is not None:
                fields.update(iteration=int(iteration), cost_rms_mm=float(cost_rms_mm))
            if job["status"] == JobState.QUEUED:
                fields.update(status=JobState.RUNNING.value, started_at=time.time())
            self.store.update_job(job_id, **fields)
