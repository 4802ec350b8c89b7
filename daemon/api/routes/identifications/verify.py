"""Verification: an identification's result predicting another campaign's lengths
(:mod:`calib.verify`, in a worker thread)."""

from __future__ import annotations

import asyncio
from typing import Any

from fastapi import APIRouter, HTTPException

from daemon.api.deps import JobId, State, WriteAuth
from daemon.api.errors import error_responses
from daemon.api.schemas import VerifyRequest

router = APIRouter(tags=["apply"], responses=error_responses(401, 404, 413, 422))


@router.post(
    "/identifications/{job_id}/verify",
    summary="Predict another campaign's lengths from a result",
    dependencies=[WriteAuth],
    responses=error_responses(400, 409),
)
async def verify_result(state: State, job_id: JobId, body: VerifyRequest) -> dict[str, Any]:
    """RMSE, MAE, STD, MAX of ``measured − predicted`` over the campaign's included samples
    and the per-pose residuals (``calib.verify``); ``refit_anchor`` fits the anchor P0 and
    zero offset first (a moved sensor). 409 if the job has no result yet, the campaign has no
    included samples, or its samples do not fit the result (an anchor the result lacks
    without ``refit_anchor``)."""
    from calib.verify import VerifyOptions, verify

    state.store.job(job_id)
    result = state.store.get_result_for_job(job_id)
    if result is None:
        raise HTTPException(409, f"identification {job_id}: has no result")
    samples, _ = state.store.sample_set(body.campaign_id)
    if len(samples) == 0:  # the campaign's state, not the request's shape: 409
        raise HTTPException(
            409, f"campaign_id: campaign {body.campaign_id} has no included samples to verify"
        )
    try:
        out = await asyncio.to_thread(
            verify, result["result"], samples, VerifyOptions(refit_anchor=body.refit_anchor)
        )
    except (ValueError, KeyError) as exc:  # the campaign's samples against the result: 409
        raise HTTPException(409, f"campaign {body.campaign_id}: {exc}") from exc
    return out.to_json()
