"""Campaigns: create, list and read them, and each one's auto-capture switch."""

from __future__ import annotations

import logging
from typing import cast

from fastapi import APIRouter, HTTPException, Request, Response, status

from daemon.api.deps import (
    AppState,
    CampaignId,
    PagedLarge,
    ReadAuth,
    State,
    WriteAuth,
    link_next,
    require_space,
)
from daemon.api.errors import error_responses
from daemon.api.routes.robots.robots import robot_for_campaign
from daemon.api.schemas import AutoCapture, CampaignCreate, CampaignOut
from daemon.monitors.autocapture import SamplerRefused, SamplerUnavailable
from daemon.store import CampaignRow

log = logging.getLogger("cablecal.service")


router = APIRouter(tags=["campaigns"], responses=error_responses(400, 401, 413, 422))


@router.post(
    "/campaigns",
    status_code=status.HTTP_201_CREATED,
    summary="Create a campaign",
    dependencies=[WriteAuth],
    responses=error_responses(429, 507),
)
def create_campaign(state: State, request: Request, body: CampaignCreate) -> CampaignOut:
    """The robot: ``robot_id`` (an existing one), or ``robot`` (its own name; default: the
    model's name) with ``robot_model`` (a built-in name or a model mapping) or
    ``robot_model_file`` (TOML or JSON text). The same robot name and model is the same robot
    again; returns the campaign with its ``id`` and ``robot_id``. 507 when the disk is at its
    free-space reserve; 429 beyond ``[requests] campaigns_per_min``."""
    require_space(state, int(request.headers.get("content-length") or 0) + 4096, "campaign")
    state.per_minute["campaign"].take(request)
    robot = robot_for_campaign(state, body)
    return _out(state, state.store.create_campaign(body.name, int(robot["id"]), body.notes))


def _out(state: AppState, row: CampaignRow) -> CampaignOut:
    """The stored campaign with what identify needs of it (:class:`CampaignOut`): cached per
    robot and anchor count, so a poll of ``GET /campaigns`` computes nothing new."""
    need = state.min_samples.get(int(row["robot_id"]), len(row["anchors"]))
    out = cast(CampaignOut, dict(row))
    out["min_training_samples"] = need.training_samples
    out["min_samples_to_identify"] = need.samples
    out["recommended_training_samples"] = need.recommended_training_samples
    out["recommended_samples"] = need.recommended_samples
    return out


@router.get("/campaigns", summary="List campaigns (paginated)", dependencies=[ReadAuth])
def list_campaigns(
    state: State, request: Request, response: Response, page: PagedLarge
) -> list[CampaignOut]:
    """By id, ``limit`` per page (default and most 500) after ``after_id``; a full page has a
    ``Link: <…>; rel="next"`` header."""
    rows = state.store.list_campaigns(after_id=page.after_id, limit=page.limit)
    link_next(request, response, rows, page.limit)
    return [_out(state, r) for r in rows]


@router.get(
    "/campaigns/{campaign_id}",
    summary="One campaign",
    dependencies=[ReadAuth],
    responses=error_responses(404),
)
def get_campaign(state: State, campaign_id: CampaignId) -> CampaignOut:
    """With ``anchors`` (of the included samples), ``min_samples_to_identify`` (the fewest
    included samples an identification with the default options accepts),
    ``min_training_samples`` and ``recommended_samples`` (the count at which outlier
    screening works)."""
    return _out(state, state.store.campaign(campaign_id))


@router.put(
    "/campaigns/{campaign_id}/auto-capture",
    summary="Auto capture on or off",
    dependencies=[WriteAuth],
    responses=error_responses(404, 503),
)
async def auto_capture(state: State, campaign_id: CampaignId, body: AutoCapture) -> CampaignOut:
    """On: the sampler captures once at each new settled pose, for this campaign only (it
    switches off any other campaign). The setting survives a daemon restart.

    Validated first (the body, the campaign, a running sampler), then stored (one
    transaction), then applied to the sampler; if the sampler refuses, the stored change is
    rolled back and the sampler put back as it was, so the database and the sampler agree.
    One switch at a time (a lock held from the store's write to the sampler's): parallel
    switches end with the database and the sampler naming the same campaign. The store's
    reads and writes run in a worker thread, the sampler's switch on the event loop that owns
    the sampler."""
    # Auto capture's one owner: daemon.monitors.autocapture.AutoCapture.
    if state.auto is None:
        state.store.campaign(campaign_id)  # 404 first
        raise HTTPException(503, "sampler: not running")
    try:
        row = await state.auto.switch(campaign_id, body.enabled, body.anchor)
    except SamplerUnavailable as exc:
        raise HTTPException(503, f"sampler: {exc}") from exc
    except SamplerRefused as exc:
        raise HTTPException(503, f"sampler: could not switch auto capture ({exc})") from exc
    return _out(state, row)
