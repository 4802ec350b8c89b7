"""Identification jobs: submit, follow, cancel, accept."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, cast

from fastapi import APIRouter, HTTPException, Request, Response, status

from daemon.api.deps import CampaignId, JobId, Paged, ReadAuth, State, WriteAuth, link_next
from daemon.api.errors import error_responses
from daemon.api.schemas import IdentificationRequest, JobOut, JobView
from daemon.jobs import JobError

router = APIRouter(tags=["identifications"], responses=error_responses(400, 401, 404, 413, 422))


def _job_view(state: State, job: Mapping[str, Any]) -> JobView:
    """The job row (the store's, or :class:`~daemon.jobs.JobManager`'s copy of it) with its
    result."""
    result = state.store.get_result_for_job(int(job["id"]))
    view = {
        **job,
        "result": result["result"] if result else None,
        "accepted": bool(result["accepted"]) if result else False,
    }
    return cast(JobView, view)


@router.post(
    "/campaigns/{campaign_id}/identifications",
    status_code=status.HTTP_202_ACCEPTED,
    summary="Start an identification job",
    dependencies=[WriteAuth],
    responses=error_responses(409),
)
async def start(state: State, campaign_id: CampaignId, body: IdentificationRequest) -> JobView:
    """Queues an identification of the campaign's included samples. Returns 202 with the job
    (``id``, ``status`` = queued); follow it at ``GET /identifications/{id}``. 422 for a body
    the schema refuses; 409, naming the option or the count, for what the campaign's robot
    and samples refuse: a parameter name the model lacks in ``fixed``/``free``, or too few
    samples left for training (after ``test_fraction``) for the parameters this robot and
    these anchors solve for (25 training rows for the built-in model with one anchor)."""
    try:
        job = state.jobs.submit(campaign_id, body.to_options())
    except JobError as exc:  # the request is well formed; the campaign's state refuses it
        raise HTTPException(409, str(exc)) from exc
    return _job_view(state, job)


@router.get(
    "/campaigns/{campaign_id}/identifications",
    summary="Jobs of a campaign (paginated)",
    dependencies=[ReadAuth],
)
def list_for_campaign(
    state: State, request: Request, response: Response, campaign_id: CampaignId, page: Paged
) -> list[JobOut]:
    """By id, ``limit`` per page (default 1000) after ``after_id``; a full page has a
    ``Link: <…>; rel="next"`` header."""
    state.store.campaign(campaign_id)  # an unknown campaign is 404, not an empty list
    rows = state.store.list_jobs(campaign_id, after_id=page.after_id, limit=page.limit)
    link_next(request, response, rows, page.limit)
    return rows


@router.get("/identifications/{job_id}", summary="Job status and result", dependencies=[ReadAuth])
def get_job(state: State, job_id: JobId) -> JobView:
    """``status`` is one of queued, running, succeeded, failed, cancelled; ``progress`` 0–1;
    ``result`` is the ``result.json`` contract of ``cablecal identify`` once succeeded."""
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
    """For results not accepted automatically (e.g. flagged implausible) after review."""
    job = state.store.job(job_id)
    if job["status"] != "succeeded":
        raise HTTPException(409, f"identification {job_id}: status is {job['status']}")
    result = state.store.get_result_for_job(job_id)
    if result is None:
        raise HTTPException(409, f"identification {job_id}: has no result")
    state.store.set_result_accepted(int(result["id"]), True)
    return _job_view(state, job)
