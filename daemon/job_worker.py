"""The worker side of an identification job (runs in a pool process of
:class:`daemon.jobs.JobManager`)."""

from __future__ import annotations

import time
from typing import Any

#: Seconds between progress messages a worker sends (the last one is always sent).
PROGRESS_INTERVAL_S = 0.2
#: Key of the worker's result that carries its final ``[iteration, cost_rms_mm]``.
FINAL_PROGRESS = "_final_progress"


def noop() -> int:
    return 0


def run_identification(
    job_id: int,
    model_mapping: dict[str, Any],
    joints_deg: list[list[float]],
    length_mm: list[float],
    anchors: list[str],
    options: dict[str, Any],
    progress_queue: Any,
    cancel_flags: Any,
    t_s: list[float] | None = None,
) -> dict[str, Any]:
    """Worker-side body of a job (runs in a pool process).

    Parameters
    ----------
    job_id : int
    model_mapping : dict
        Nominal model, as :func:`calib.models.model_from_mapping` reads it.
    joints_deg : list of n lists of 6 floats
        Joint angles [deg].
    length_mm : list of n floats
        Cable lengths [mm].
    anchors : list of n str
        Anchor id per sample.
    options : dict
        Keyword arguments of :class:`calib.options.IdentifyOptions`.
    progress_queue, cancel_flags
        Manager proxies: ``(job_id, fraction, message, iteration, cost_rms_mm)`` tuples go
        out (the last two None until the solver finishes its first iteration);
        ``cancel_flags[job_id]`` set true asks the job to stop.
    t_s : list of n floats, optional
        Capture time of each sample [s] (:meth:`daemon.store.Store.sample_set`), for the
        drift model; None: the row order.

    Returns
    -------
    dict
        The ``result.json`` contract of :meth:`calib.identify.IdentifyResult.to_json`.
    """
    from calib.dataset import make_samples
    from calib.identify import identify
    from calib.models import model_from_mapping
    from calib.options import options_from_mapping
    from calib.solvers.common import Cancelled

    model = model_from_mapping(model_mapping)
    samples = make_samples(joints_deg, length_mm, anchors, t_s=t_s)  # t_s: for the drift model
    opts = options_from_mapping(options)
    progress_queue.put((job_id, 0.0, "started", None, None))
    last = [time.monotonic()]
    newest: list[Any] = [None, None]  # the newest (iteration, cost_rms_mm), kept between sends

    def progress(
        fraction: float,
        message: str,
        /,
        *,
        cost_rms_mm: float | None = None,
        iteration: int | None = None,
    ) -> None:
        if cancel_flags.get(job_id):
            raise Cancelled(f"job {job_id} cancelled")
        if cost_rms_mm is not None and iteration is not None:
            newest[:] = [int(iteration), float(cost_rms_mm)]
        now = time.monotonic()
        if now - last[0] >= PROGRESS_INTERVAL_S or fraction >= 1.0:
            last[0] = now
            progress_queue.put((job_id, float(fraction), message, *newest))

    out = identify(model, samples, opts, progress=progress, clock=time.perf_counter).to_json()
    # The newest iteration and cost, for the job row (the last queued message may arrive
    # after the job is marked finished and is then dropped).
    out[FINAL_PROGRESS] = list(newest)
    return out
