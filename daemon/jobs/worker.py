"""The worker side of an identification job (runs in a pool process of
:class:`daemon.jobs.manager.JobManager`)."""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any, NamedTuple

if TYPE_CHECKING:
    from calib.dataset import SampleSet
    from calib.models import RobotModel
    from calib.options import IdentifyOptions
    from calib.split import Checked as CheckedOptions

#: Seconds between progress messages a worker sends (the last one is always sent).
PROGRESS_INTERVAL_S = 0.2
#: Key of the worker's result that carries its final ``[iteration, cost_rms_mm]``.
FINAL_PROGRESS = "_final_progress"
#: A campaign with more included samples than this is checked and snapshotted in a worker
#: process (no shared GIL with the event loop; its memory returned after), a smaller one in a
#: worker thread (a process costs tens of milliseconds to start) [samples].
CHILD_CHECK_SAMPLES = 20_000


class JobError(ValueError):
    """A job request cannot run (names the field)."""


class JobsFull(RuntimeError):
    """``max_pending`` jobs are queued or running (a 429)."""


class Checked(NamedTuple):
    """A checked job request: the samples and their ids, the robot, and the options checked
    against them with the split identify will run on (:func:`calib.split.check`)."""

    samples: SampleSet
    sample_ids: list[int]
    robot_id: int
    model: RobotModel
    checked: CheckedOptions


class Prepared(NamedTuple):
    """A checked job with its inputs: the campaign and robot, the checked options and split
    (:class:`calib.split.Checked`), the samples' ids, and the model mapping, joints [deg]
    (n x 6 array), lengths [mm] (n array), anchors (n), capture times [s] (n array, or
    None) and pose groups (n, or None) of :func:`run_identification`."""

    campaign_id: int
    robot_id: int
    checked: CheckedOptions
    sample_ids: list[int]
    inputs: tuple[Any, ...]


def check_job(store: Any, campaign_id: int, options: IdentifyOptions) -> Checked:
    """What an identification of the campaign's included samples with ``options`` (made once,
    from the request) would run on, after the one rule of what can run
    (:func:`calib.split.check`: the split identify will use, then
    :func:`calib.options.validate`: parameter names, training rows, each anchor's training
    rows). The worker runs on this check's result without checking again.

    Raises
    ------
    JobError
        Bad options (the message names the option) or too few samples.
    daemon.store.StoreNotFound
        No such campaign.
    """
    from calib.options import OptionError
    from calib.split import check
    from daemon.store import StoreNotFound

    campaign = store.get_campaign(campaign_id)
    if campaign is None:
        raise StoreNotFound("campaign", campaign_id)
    samples, sample_ids = store.sample_set(campaign_id)
    robot_id = int(campaign["robot_id"])
    model = store.robot_model(robot_id)
    try:
        checked = check(model, samples, options)
    except OptionError as exc:
        raise JobError(str(exc)) from exc
    except (TypeError, ValueError) as exc:
        raise JobError(f"campaign {campaign_id}: {exc}") from exc
    return Checked(samples, sample_ids, robot_id, model, checked)


def prepare_job(store: Any, campaign_id: int, options: IdentifyOptions) -> Prepared:
    """:func:`check_job` and the job's inputs (arrays: they pickle as their bytes)."""
    samples, sample_ids, robot_id, model, checked = check_job(store, campaign_id, options)
    inputs = (model.to_dict(), samples.joints_deg, samples.length_mm, list(samples.anchor))
    extra = (samples.t_s, None if samples.group is None else list(samples.group))
    return Prepared(campaign_id, robot_id, checked, sample_ids, (*inputs, *extra))


def prepare_in_child(
    db_path: str,
    campaign_id: int,
    options: IdentifyOptions,
    check_only: bool,
) -> Prepared | None:
    """:func:`prepare_job` (or, with ``check_only``, only :func:`check_job`: None) in a
    worker process (:func:`daemon.process.workers.run_in_child`), on the store opened read-only.

    Raises
    ------
    JobError
        As :func:`check_job`; a campaign that is gone is one too (the route looked it up
        first, so only a race gets here).
    """
    from daemon.store import Store, StoreNotFound

    store = Store(db_path, readonly=True)
    try:
        if check_only:
            check_job(store, campaign_id, options)
            return None
        return prepare_job(store, campaign_id, options)
    except StoreNotFound as exc:
        raise JobError(f"{exc.kind} {exc.id}: {exc.reason}") from None
    finally:
        store.close()


def noop() -> int:
    return 0


def run_identification(
    job_id: int,
    model_mapping: dict[str, Any],
    joints_deg: Any,
    length_mm: Any,
    anchors: list[str],
    checked: CheckedOptions,
    progress_queue: Any,
    cancel_flags: Any,
    t_s: Any = None,
    group: list[str] | None = None,
) -> dict[str, Any]:
    """Worker-side body of a job (runs in a pool process).

    Parameters
    ----------
    job_id : int
    model_mapping : dict
        Nominal model, as :func:`calib.models.model_from_mapping` reads it.
    joints_deg : array or list, shape (n, 6)
        Joint angles [deg].
    length_mm : array or list, shape (n,)
        Cable lengths [mm].
    anchors : list of n str
        Anchor id per sample.
    checked : calib.split.Checked
        The options and split :func:`check_job` checked on these samples (not checked
        again: :func:`calib.identify.identify_checked`).
    progress_queue, cancel_flags
        Manager proxies: ``(job_id, fraction, message, iteration, cost_rms_mm)`` tuples go
        out (the last two None until the solver finishes its first iteration);
        ``cancel_flags[job_id]`` set true asks the job to stop.
    t_s : array or list, shape (n,), optional
        Capture time of each sample [s] (:meth:`daemon.store.Store.sample_set`), for the
        drift model; None: the row order.
    group : list of n str, optional
        Pose group of each sample (the grouped hold-out's and the prior's cross-validation
        folds, as the job's check saw them); None: Ward clusters of the joints.

    Returns
    -------
    dict
        The ``result.json`` contract of :meth:`calib.identify.IdentifyResult.to_json`.
    """
    from calib.dataset import make_samples
    from calib.identify import identify_checked
    from calib.models import model_from_mapping
    from calib.solvers.common import Cancelled

    model = model_from_mapping(model_mapping)
    # t_s: for the drift model; group: the same samples the job's check split
    samples = make_samples(joints_deg, length_mm, anchors, group=group, t_s=t_s)
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

    result = identify_checked(model, samples, checked, progress=progress, clock=time.perf_counter)
    out = result.to_json()
    # The newest iteration and cost, for the job row (the last queued message may arrive
    # after the job is marked finished and is then dropped).
    out[FINAL_PROGRESS] = list(newest)
    return out
