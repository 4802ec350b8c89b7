"""Pose plans of a campaign: plan (``calib.planning``, off the event loop) and follow progress.

The request body, :class:`daemon.api.schemas.PlanRequest`, takes its defaults from
:class:`calib.planning.PlanOptions` (one definition); the response bodies live here, and the
plan's summary is :meth:`calib.planning.PlanResult.to_json` as it is.
"""

from __future__ import annotations

import asyncio
import time
from typing import Any, Literal

from fastapi import APIRouter, HTTPException, Query, Request, status
from typing_extensions import TypedDict

from calib.csvtext import write_csv
from calib.dataset import SampleError, SampleSet
from calib.models import RobotModel
from calib.planning import CSV_COLUMNS, PlanOptions, plan, start_anchors_mm
from calib.planning.progress import MATCH_TOL_DEG, match_plan
from calib.programs.formats import DEFAULT_SPEED_PCT
from daemon.api.deps import CampaignId, ReadAuth, State, WriteAuth
from daemon.api.errors import error_responses, unprocessable
from daemon.api.program_download import FORMAT_HELP, DownloadFormat, DwellS, SpeedPct, download
from daemon.api.schemas import MAX_ANCHOR_CHARS, PlanRequest
from daemon.plan_noise import NoiseEstimate, cell_noise
from daemon.store.plans import PlanHeader, PlannedPoseRow, PlanRow

router = APIRouter(tags=["plans"], responses=error_responses(401, 404, 413, 422))


class PlannedPose(PlannedPoseRow):
    """A planned pose with its state: ``done`` once a sample of the campaign measured it."""

    status: Literal["done", "pending"]
    sample_id: int | None


class PlanProgress(TypedDict):
    """Counts, the tolerance used and the first pending pose in visiting order."""

    n_planned: int
    n_done: int
    n_pending: int
    fraction_done: float
    tol_deg: float
    next_pose: int | None


class PlanView(PlanHeader):
    """A stored plan with each pose's state and the progress."""

    poses: list[PlannedPose]
    progress: PlanProgress


def _view(state: State, stored: PlanRow, tol_deg: float) -> PlanView:
    """The plan with each pose done or pending against the campaign's included samples."""
    samples, sample_ids = state.store.sample_set(stored["campaign_id"])  # included ones
    poses = stored["poses"]
    match = match_plan(poses, samples.joints_deg, [str(a) for a in samples.anchor], tol_deg)
    out: list[PlannedPose] = []
    for pose, k in zip(poses, match, strict=True):
        done = k >= 0
        out.append({**pose, "status": "done" if done else "pending",
                    "sample_id": sample_ids[k] if done else None})  # fmt: skip
    n_done = sum(1 for k in match if k >= 0)
    pending = [p["pose"] for p in out if p["status"] == "pending"]
    progress: PlanProgress = {
        "n_planned": len(out), "n_done": n_done, "n_pending": len(out) - n_done,
        "fraction_done": n_done / len(out), "tol_deg": tol_deg,
        "next_pose": int(pending[0]) if pending else None,
    }  # fmt: skip
    return {**stored, "poses": out, "progress": progress}


def _compute(
    model: RobotModel, body: PlanRequest, start: SampleSet | None, noise: NoiseEstimate
) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """Run the planning (in a worker thread): the summary (with ``noise_source`` and
    ``noise_detail``: where its ``noise_mm`` came from) and the poses."""
    opts = body.options(noise.noise_mm)
    anchors = body.anchors_mm
    found = {}
    if start is not None:
        try:  # where the samples put the anchors (plan() needs it too)
            found = start_anchors_mm(model, start)
        except (ValueError, SampleError) as exc:  # the campaign's samples: its state, 409
            raise HTTPException(409, f"start_from_samples: {exc}") from exc
    if anchors is None:
        if start is None:
            raise ValueError("anchors_mm: required unless start_from_samples is true")
        anchors = [[float(p[0]), float(p[1]), float(p[2])] for p in found.values()]
        if body.anchor_ids is None:
            opts = PlanOptions(**{**opts.__dict__, "anchor_ids": tuple(found)})
    res = plan(model, anchors, opts, start=start, clock=time.perf_counter)
    summary = res.to_json()
    summary.update(noise_source=noise.source, noise_detail=noise.detail)
    return summary, res.csv_rows()


def _loc(message: str) -> tuple[str, ...]:
    """The location of an engine error: ``("body", "<option>")`` when the message starts with
    an option's name (``"candidates: ..."``), else ``("body",)``."""
    name = message.split(":", 1)[0].strip()
    return ("body", name) if name in PlanRequest.model_fields else ("body",)


@router.post(
    "/campaigns/{campaign_id}/plan",
    status_code=status.HTTP_201_CREATED,
    summary="Plan the campaign's poses",
    dependencies=[WriteAuth],
    responses={
        **error_responses(400),
        409: {**error_responses(409)[409], "description": "Another plan is being computed"},
    },
)
async def make_plan(
    state: State, request: Request, campaign_id: CampaignId, body: PlanRequest
) -> PlanView:
    """Plans ``n`` poses for the campaign's robot (D-optimal on its identifiable parameters;
    ``cablecal plan`` does the same from the command line) and stores the plan. The planning
    runs in a worker thread, so the service keeps serving; one plan at a time (409 while
    another runs). A bad option is a 422 naming it. Returns the plan as ``GET`` does."""
    campaign = state.store.campaign(campaign_id)  # 404 first
    model = state.store.robot_model(int(campaign["robot_id"]))
    start = state.store.sample_set(campaign_id)[0] if body.start_from_samples else None
    if start is not None and len(start) == 0:
        raise HTTPException(409, "start_from_samples: the campaign has no included samples")
    if getattr(request.app.state, "planning_campaign", None) is not None:
        raise HTTPException(409, "plan: another plan is being computed; try again later")
    request.app.state.planning_campaign = campaign_id
    try:
        noise = (
            NoiseEstimate(body.noise_mm, "request", "given in the plan request")
            if body.noise_mm is not None
            else await asyncio.to_thread(
                cell_noise, state.store, state.sampler, state.settings.sampler, campaign_id,
                int(campaign["robot_id"]),
            )
        )  # fmt: skip
        summary, poses = await asyncio.to_thread(_compute, model, body, start, noise)
    except (ValueError, SampleError) as exc:  # numpy's LinAlgError is a ValueError
        raise unprocessable(_loc(str(exc)), str(exc)) from exc
    finally:
        request.app.state.planning_campaign = None
    options = body.model_dump(mode="json")
    stored = state.store.save_plan(campaign_id, options, summary, poses)
    return _view(state, stored, MATCH_TOL_DEG)


def _plan_csv(stored: PlanRow) -> str:
    """The stored plan's poses as ``cablecal plan`` writes them (columns ``CSV_COLUMNS``)."""
    return write_csv(({k: p.get(k) for k in CSV_COLUMNS} for p in stored["poses"]), CSV_COLUMNS)


@router.get(
    "/campaigns/{campaign_id}/plan",
    summary="The campaign's plan and its progress",
    dependencies=[ReadAuth],
    response_model=PlanView,
    responses={200: {"content": {"text/csv": {}, "text/plain": {}}}, **error_responses(409)},
)
def get_plan(
    state: State,
    campaign_id: CampaignId,
    tol_deg: float = Query(
        MATCH_TOL_DEG,
        gt=0,
        le=10,
        allow_inf_nan=False,
        description="Largest joint difference [deg] for a sample to count as a planned pose",
    ),
    format: DownloadFormat | None = Query(None, description=FORMAT_HELP),
    speed_pct: SpeedPct = DEFAULT_SPEED_PCT,
    dwell_s: DwellS = None,
    anchor: str | None = Query(
        None,
        min_length=1,
        max_length=MAX_ANCHOR_CHARS,
        description="Program formats, a plan for several anchors: this anchor's poses.",
    ),
) -> Any:
    """The newest plan: its options, summary (condition number, 1σ per base parameter,
    predicted TCP σ plan vs random, times) and poses in visiting order, each ``done`` (with
    the ``sample_id`` that measured it) or ``pending``. A pose is done when an included
    sample of the campaign at the same anchor has every joint within ``tol_deg`` of it, so
    manual, automatic and imported captures all count, and excluding a sample makes its pose
    pending again. 404 when the campaign has no plan.

    With ``format``, the poses as a download instead: ``csv`` (``cablecal plan``'s CSV) or a
    robot program (each pose a joint move to a fine stop, then a dwell of ``dwell_s``, default
    from the sampler's ``settle_s``; ``cablecal program`` writes the same)."""
    stored = state.store.latest_plan(campaign_id)
    if format is None:
        return _view(state, stored, tol_deg)
    model = state.store.robot_model(int(stored["robot_id"]))
    return download(
        _plan_csv(stored),
        str(format.value),
        stem=f"campaign-{campaign_id}-plan",
        model=model,
        what=f"plan {stored['id']} of campaign {campaign_id}",
        speed_pct=speed_pct,
        dwell_s=dwell_s,
        settle_s=state.settings.sampler.settle_s,
        anchor=anchor,
    )
