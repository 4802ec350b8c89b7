"""Identification jobs: submit, follow, cancel, accept."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, HTTPException, status

from daemon.api.deps import ReadAuth, State, WriteAuth
from daemon.api.schemas import IdentificationRequest
from daemon.jobs import JobError

router = APIRouter(tags=["identifications"])


def _job_view(state: State, job: dict[str, Any]) -> dict[str, Any]:
    out = dict(job)
    result = state.store.get_result_for_job(int(job["id"]))
    out["result"] = result["result"] if result else None
    out["accepted"] = bool(result["accepted"]) if result else False
    return out


@router.post(
    "/campaigns/{campaign_id}/identifications",
    status_code=status.HTTP_202_ACCEPTED,
    summary="Start an identification job",
    dependencies=[WriteAuth],
)
async def start(state: State, campaign_id: int, body: IdentificationRequest) -> dict[str, Any]:
    """Queues an identification of the campaign's included samples. Returns 202 with the job
    (``id``, ``status`` = queued); follow it at ``GET /identifications/{id}``."""
    try:
        job = state.jobs.submit(campaign_id, body.to_options())
    except JobError as exc:
        raise HTTPException(422, str(exc)) from exc
    return _job_view(state, job)


@router.get(
    "/campaigns/{campaign_id}/identifications",
    summary="Jobs of a campaign",
    dependencies=[ReadAuth],
)
def list_for_campaign(state: State, campaign_id: int) -> list[dict[str, Any]]:
    if state.store.get_campaign(campaign_id) is None:
        raise HTTPException(404, f"campaign {campaign_id}: not found")
    return [dict(j) for j in state.store.list_jobs(campaign_id)]


@router.get("/identifications/{job_id}", summary="Job status and result", dependencies=[ReadAuth])
def get_job(state: State, job_id: int) -> dict[str, Any]:
    """``status`` is one of queued, running, succeeded, failed, cancelled; ``progress`` 0–1;
    ``result`` is the ``result.json`` contract of ``cablecal identify`` once succeeded."""
    job = state.store.get_job(job_id)
    if job is None:
        raise HTTPException(404, f"identification {job_id}: not found")
    return _job_view(state, job)


@router.delete("/identifications/{job_id}", summary="Cancel a job", dependencies=[WriteAuth])
def cancel(state: State, job_id: int) -> dict[str, Any]:
    """A queued job is cancelled at once; a running one stops at its next progress step."""
    return _job_view(state, state.jobs.cancel(job_id))


@router.post(
    "/identifications/{job_id}/accept",
    summary="Accept a result as the robot's calibrated model",
    dependencies=[WriteAuth],
)
def accept(state: State, job_id: int) -> dict[str, Any]:
    """For results not accepted automatically (e.g. flagged implausible) after review."""
    job = state.store.get_job(job_id)
    if job is None:
        raise HTTPException(404, f"identification {job_id}: not found")
    if job["status"] != "succeeded":
        raise HTTPException(409, f"identification {job_id}: status is {job['status']}")
    result = state.store.get_result_for_job(job_id)
    if result is None:
        raise HTTPException(409, f"identification {job_id}: has no result")
    state.store.set_result_accepted(int(result["id"]), True)
    return _job_view(state, dict(job))
