"""Identification jobs: submit, follow, cancel, compare with the current calibration, accept;
and the option spec the page builds its form from."""

from __future__ import annotations

import asyncio
from collections.abc import Mapping
from dataclasses import replace
from typing import Annotated, Any, cast

from fastapi import APIRouter, HTTPException, Query, Request, Response, status
from typing_extensions import TypedDict

from calib.compare import Comparison, compare_results
from calib.options import (
    Holdout,
    IdentifyOptions,
    default,
    held_out,
    samples_for_training_rows,
    spec,
)
from daemon.api.deps import (
    CampaignId,
    JobId,
    PagedLarge,
    ReadAuth,
    State,
    WriteAuth,
    link_next,
    require_space,
)
from daemon.api.errors import error_responses
from daemon.api.http.offload import offload
from daemon.api.option_spec import IdentifyOptionsSpec, identify_options_spec
from daemon.api.schemas import IdentificationRequest, JobView
from daemon.jobs.worker import CHILD_CHECK_SAMPLES, JobError, JobsFull, prepare_in_child
from daemon.process.workers import run_in_child
from daemon.store import JobRow, JobState

#: Largest sample count the readiness route reports (a test fraction near 1 needs absurdly
#: many samples: the answer is then null, not a long search).
MAX_READINESS_SAMPLES = 10_000_000

#: Room kept for a job's stored result [bytes] (its JSON: parameters, covariance, residuals).
RESULT_BYTES = 4 * 1024 * 1024

router = APIRouter(tags=["identifications"], responses=error_responses(400, 401, 404, 413, 422))


def _job_view(state: State, job: Mapping[str, Any]) -> JobView:
    """The job row (the store's, or :class:`~daemon.jobs.manager.JobManager`'s copy of it) with its
    result."""
    result = state.store.get_result_for_job(int(job["id"]))
    view = {
        **job,
        "result": result["result"] if result else None,
        "accepted": bool(result["accepted"]) if result else False,
    }
    return cast(JobView, view)


@router.get("/options/identify", summary="Identification options", dependencies=[ReadAuth])
def options(state: State) -> IdentifyOptionsSpec:
    """Each field of the ``POST /campaigns/{id}/identifications`` body: its ``type``,
    ``default``, bounds (``gt``/``ge``/``lt``/``le``), ``choices`` and ``help``, from
    :mod:`calib.options` (the one home of an option); and the job states, ``finished`` the
    ones after which nothing changes. The operator page builds its form from this."""
    return identify_options_spec(state.settings.jobs.noise_mm)


class Readiness(TypedDict):
    """Whether the campaign has enough samples at ``test_fraction``: ``n_included`` samples
    split into ``n_train`` / ``n_test``; ``min_training_samples`` for this robot and these
    anchors, ``min_samples`` the fewest included samples at this test fraction; ``ready``
    exactly when ``POST /campaigns/{id}/identifications`` with this test fraction would be
    accepted, and ``reason`` why not (the 409's message: too few training rows, or too few at
    an anchor), else null."""

    test_fraction: float
    n_included: int
    n_train: int
    n_test: int
    min_training_samples: int
    min_samples: int | None
    ready: bool
    reason: str | None


@router.get(
    "/campaigns/{campaign_id}/identification-readiness",
    summary="Enough samples to identify at a test fraction?",
    dependencies=[ReadAuth],
    responses=error_responses(429, 503),
)
async def readiness(
    state: State,
    request: Request,
    campaign_id: CampaignId,
    test_fraction: Annotated[
        float, Query(ge=spec("test_fraction").ge, lt=spec("test_fraction").lt, allow_inf_nan=False)
    ] = default("test_fraction"),
    holdout: Annotated[Holdout, Query(description=spec("holdout").help)] = default("holdout"),
    seed: Annotated[
        int, Query(ge=spec("seed").ge, le=spec("seed").le, description=spec("seed").help)
    ] = default("seed"),
) -> Readiness:
    """The minimum-samples rule applied for the page (which keeps no copy of it): the split
    of the campaign's included samples at ``test_fraction`` (with the ``holdout`` and
    ``seed`` of the POST: a grouped hold-out may leave an anchor short where a random one
    does not) and the counts identify needs (``min_samples`` null when it would exceed
    :data:`MAX_READINESS_SAMPLES`). The check runs in a worker thread, as the POST's (429
    when too many wait)."""
    row = state.store.campaign(campaign_id)
    need = state.min_samples.get(int(row["robot_id"]), len(row["anchors"])).training_samples
    n = int(row["n_included"])
    n_test = held_out(n, test_fraction)
    options = IdentifyOptions(test_fraction=test_fraction, holdout=holdout, seed=seed)
    if state.settings.jobs.noise_mm is not None:  # as the POST's options: the [jobs] default
        options = replace(options, noise_mm=state.settings.jobs.noise_mm)
    try:  # the rule POST applies (the job manager's check), per anchor included
        await _checked(state, request, campaign_id, options, n, check_only=True)
        reason = None
    except JobError as exc:
        reason = str(exc)
    return {
        "test_fraction": test_fraction,
        "n_included": n,
        "n_train": n - n_test,
        "n_test": n_test,
        "min_training_samples": need,
        "min_samples": samples_for_training_rows(need, test_fraction)
        if need / (1.0 - test_fraction) <= MAX_READINESS_SAMPLES
        else None,
        "ready": reason is None,
        "reason": reason,
    }


async def _checked(
    state: State,
    request: Request,
    campaign_id: int,
    options: IdentifyOptions,
    n_samples: int,
    check_only: bool,
) -> Any:
    """The job manager's check (``check_only``: None) or prepared job, behind the check gate:
    in a worker thread for a campaign of at most :data:`CHILD_CHECK_SAMPLES` samples, else in
    a worker process (killed when the client leaves), so the event loop keeps the GIL."""
    if n_samples <= CHILD_CHECK_SAMPLES:
        run = state.jobs.check if check_only else state.jobs.prepare

        async def in_thread() -> Any:
            return await asyncio.to_thread(run, campaign_id, options)

        return await offload(request, state.gates["check"], in_thread, cancel_on_leave=False)
    s, path = state.settings.jobs, str(state.settings.database_path)
    args = (path, campaign_id, options, check_only)

    async def in_child() -> Any:
        # At the daemon's own priority: a request waits on it (at worker_nice 10 on a machine
        # busy with other work, a 350k-row check took 80 s instead of 11 s), and in a process
        # of its own it shares no GIL with the event loop (bench/hardening5_identify.md).
        return await run_in_child(
            prepare_in_child, *args, nice=0, blas_threads=s.worker_blas_threads
        )

    return await offload(request, state.gates["check"], in_child)


@router.post(
    "/campaigns/{campaign_id}/identifications",
    status_code=status.HTTP_202_ACCEPTED,
    summary="Start an identification job",
    dependencies=[WriteAuth],
    responses=error_responses(409, 429, 503, 507),
)
async def start(
    state: State, request: Request, campaign_id: CampaignId, body: IdentificationRequest
) -> JobView:
    """Queues an identification of the campaign's included samples. Returns 202 with the job
    (``id``, ``status`` = queued); follow it at ``GET /identifications/{id}``. 422 for a body
    the schema refuses; 409, naming the option or the count, for what the campaign's robot
    and samples refuse: a parameter name the model lacks in ``fixed``/``free``, or too few
    samples left for training (after ``test_fraction``) for the parameters this robot and
    these anchors solve for (25 training rows for the built-in model with one anchor). The
    check and the samples' snapshot run in a worker thread, not on the event loop; 429 with
    ``Retry-After`` when ``[jobs] max_pending`` jobs are queued or running, or too many
    checks wait."""
    require_space(state, RESULT_BYTES, "identification")  # its result is stored at the end
    retry = {"Retry-After": str(state.settings.requests.retry_after_s)}
    if why := state.jobs.full():
        raise HTTPException(429, why, headers=retry)
    options = body.to_options(state.settings.jobs.noise_mm)  # made once, passed on
    n = int(state.store.campaign(campaign_id)["n_included"])  # 404 first
    try:
        prepared = await _checked(state, request, campaign_id, options, n, check_only=False)
        job = state.jobs.enqueue(prepared)
    except JobError as exc:  # the request is well formed; the campaign's state refuses it
        raise HTTPException(409, str(exc)) from exc
    except JobsFull as exc:
        raise HTTPException(429, str(exc), headers=retry) from exc
    return _job_view(state, job)


@router.get(
    "/campaigns/{campaign_id}/identifications",
    summary="Jobs of a campaign (paginated)",
    dependencies=[ReadAuth],
)
def list_for_campaign(
    state: State, request: Request, response: Response, campaign_id: CampaignId, page: PagedLarge
) -> list[JobRow]:
    """By id, ``limit`` per page (default and most 500) after ``after_id``; a full page has a
    ``Link: <…>; rel="next"`` header."""
    state.store.campaign(campaign_id)  # an unknown campaign is 404, not an empty list
    rows = state.store.list_jobs(campaign_id, after_id=page.after_id, limit=page.limit)
    link_next(request, response, rows, page.limit)
    return rows


@router.get("/identifications/{job_id}", summary="Job status and result", dependencies=[ReadAuth])
def get_job(state: State, job_id: JobId) -> JobView:
    """``status`` is a job state (``GET /options/identify``); ``progress`` has ``fraction``
    0–1 and, once the solver finished an iteration, ``iteration`` (whole iterations over the
    fit) and ``cost_rms_mm`` (its data RMS [mm]); ``result`` is the ``result.json`` contract
    of ``cablecal identify`` once succeeded; ``current`` whether it is the robot's current
    calibration."""
    return _job_view(state, state.store.job(job_id))


@router.delete("/identifications/{job_id}", summary="Cancel a job", dependencies=[WriteAuth])
def cancel(state: State, job_id: JobId) -> JobView:
    """A queued job is cancelled at once; a running one stops at its next progress step."""
    return _job_view(state, state.jobs.cancel(job_id))


@router.post(
    "/identifications/{job_id}/accept",
    summary="Accept a result as the robot's calibrated model",
    dependencies=[WriteAuth],
    responses=error_responses(409),
)
def accept(state: State, job_id: JobId) -> JobView:
    """Makes the result the robot's current calibration, replacing the previous one (a
    robot's first plausible result is accepted automatically; a later one, or an implausible
    one, waits for this after review: see ``GET /identifications/{id}/compare``)."""
    job = state.store.job(job_id)
    if job["status"] != JobState.SUCCEEDED:
        raise HTTPException(409, f"identification {job_id}: status is {job['status']}")
    result = state.store.get_result_for_job(job_id)
    if result is None:
        raise HTTPException(409, f"identification {job_id}: has no result")
    previous = state.store.current_job_id(int(job["robot_id"]))
    state.store.set_result_accepted(int(result["id"]), True)
    if previous != job_id:
        replaced = f" (replaces job {previous})" if previous is not None else ""
        state.store.update_job(job_id, message=f"accepted: the current calibration{replaced}")
    return _job_view(state, state.store.job(job_id))


@router.get(
    "/identifications/{job_id}/compare",
    summary="A result next to the robot's current calibration",
    dependencies=[ReadAuth],
    responses=error_responses(409),
)
def compare(state: State, job_id: JobId) -> Comparison:
    """Old (the robot's current calibration) and new (this job's result) side by side:
    length RMSE [mm] of both models on this job's held-out rows (the same rows), the
    predicted TCP 1σ [mm] of each, and the parameters that changed by more than 0.001 mm
    or deg. ``current`` is null when the robot has no calibration yet. 409 when the job has
    no result."""
    job = state.store.job(job_id)
    new = state.store.get_result_for_job(job_id)
    if new is None:
        raise HTTPException(409, f"identification {job_id}: has no result")
    current_id = state.store.current_job_id(int(job["robot_id"]))
    old = None if current_id is None else state.store.get_result_for_job(current_id)
    samples, sample_ids = state.store.sample_set(int(job["campaign_id"]))
    return compare_results(
        job_id, new["result"], current_id, old and old["result"], samples, sample_ids
    )
