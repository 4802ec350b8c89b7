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
from calib.planning import CSV_COLUMNS, PlanOptions, plan
from calib.planning.progress import MATCH_TOL_DEG, match_plan, not_capturable
from calib.planning.start import plan_anchor_ids, start_anchor_fits
from calib.programs.formats import DEFAULT_SPEED_PCT
from calib.result import CalibrationResult
from daemon.api.deps import CampaignId, ReadAuth, State, WriteAuth
from daemon.api.errors import error_responses, unprocessable
from daemon.api.plan_noise import NoiseEstimate, cell_noise
from daemon.api.program_download import FORMAT_HELP, DownloadFormat, DwellS, SpeedPct, download
from daemon.api.schemas import PlanRequest
from daemon.api.text_rules import MAX_ANCHOR_CHARS
from daemon.jobs.plan_check import rejections
from daemon.store import StoreNotFound
from daemon.store.plans import PlanHeader, PlannedPoseRow, PlanRow

router = APIRouter(tags=["plans"], responses=error_responses(401, 404, 413, 422))


class PlannedPose(PlannedPoseRow):
    """A planned pose with its state: ``done`` once a sample of the campaign measured it,
    ``not_capturable`` when the sampler refused it for good (``why``: the refusal, e.g. the
    indicator over its range there), else ``pending``."""

    status: Literal["done", "pending", "not_capturable"]
    sample_id: int | None
    why: str | None


class PlanProgress(TypedDict):
    """Counts (poses that cannot be captured apart from the pending ones), the tolerance used
    and the first pending pose in visiting order."""

    n_planned: int
    n_done: int
    n_pending: int
    n_not_capturable: int
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
    why = not_capturable(poses, match, rejections(state.store, stored["campaign_id"]), tol_deg)
    out: list[PlannedPose] = []
    for pose, k, w in zip(poses, match, why, strict=True):
        done = k >= 0
        status: Literal["done", "pending", "not_capturable"] = (
            "done" if done else "not_capturable" if w else "pending"
        )
        out.append(
            {**pose, "status": status, "sample_id": sample_ids[k] if done else None, "why": w}
        )
    n_done = sum(1 for k in match if k >= 0)
    n_not = sum(1 for w in why if w)
    pending = [p["pose"] for p in out if p["status"] == "pending"]
    progress: PlanProgress = {
        "n_planned": len(out),
        "n_done": n_done,
        "n_pending": len(pending),
        "n_not_capturable": n_not,
        "fraction_done": n_done / len(out),
        "tol_deg": tol_deg,
        "next_pose": int(pending[0]) if pending else None,
    }
    return {**stored, "poses": out, "progress": progress}


#: An anchor's zero offset [mm] and where it came from.
Offset = tuple[float, str]


def known_offsets(state: State, campaign_id: int, robot_id: int) -> dict[str, Offset]:
    """The indicator's zero offset per anchor id that a plan predicts readings with: the
    campaign's running fit (the sensor watch's), else the robot's accepted calibration."""
    out: dict[str, Offset] = {}
    try:
        accepted = state.store.accepted_result(robot_id)
    except StoreNotFound:  # none accepted yet
        accepted = None
    if accepted is not None:
        res = CalibrationResult.from_json(accepted["result"])
        label = f"the accepted calibration (result #{accepted['id']})"
        if res.anchor_id is not None and res.length_offset_mm is not None:
            out[res.anchor_id] = (res.length_offset_mm, label)
        for aid, a in res.anchors.items():
            out[aid] = (a.length_offset_mm, label)
    if state.watch is not None:
        for aid, c in state.watch.offsets_mm(campaign_id).items():
            out[aid] = (c, "the campaign's running fit")
    return out


def _compute(
    model: RobotModel,
    body: PlanRequest,
    start: SampleSet | None,
    noise: NoiseEstimate,
    known: dict[str, Offset] | None = None,
) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """Run the planning (in a worker thread): the summary (with ``noise_source`` and
    ``noise_detail``: where its ``noise_mm`` came from; ``reading_mm.offset_source``: where
    the zero offsets came from) and the poses. ``known``: zero offsets per anchor id
    (:func:`known_offsets`); the start samples' multilateration fills in the others."""
    opts = body.options(noise.noise_mm)
    anchors = body.anchors_mm
    found = {}
    offsets = dict(known or {})
    if start is not None:
        try:  # where the samples put the anchors (plan() needs it too)
            fits = start_anchor_fits(model, start)
        except (ValueError, SampleError) as exc:  # the campaign's samples: its state, 409
            raise HTTPException(409, f"start_from_samples: {exc}") from exc
        found = {aid: p0 for aid, (p0, _) in fits.items()}
        for aid, (_, c) in fits.items():
            offsets.setdefault(aid, (float(c), "the campaign's samples"))
    if anchors is None:
        if start is None:
            raise ValueError("anchors_mm: required unless start_from_samples is true")
        # With anchor_ids, new poses go to those anchors only (after a sensor move: the
        # anchor in use, not the old one); the other anchors' samples still inform the plan.
        wanted = tuple(found) if body.anchor_ids is None else tuple(body.anchor_ids)
        if missing := [aid for aid in wanted if aid not in found]:
            raise ValueError(
                f"anchor_ids: anchor {missing[0]} has no included sample to place it; give "
                "anchors_mm (the sensor position) for it"
            )
        anchors = [[float(v) for v in found[aid][:3]] for aid in wanted]
        opts = PlanOptions(**{**opts.__dict__, "anchor_ids": wanted})
    ids = plan_anchor_ids(opts.anchor_ids, len(anchors))
    used = [offsets.get(aid) for aid in ids]
    if any(u is not None for u in used):
        values = tuple(None if u is None else u[0] for u in used)
        opts = PlanOptions(**{**opts.__dict__, "offsets_mm": values})
    res = plan(model, anchors, opts, start=start, clock=time.perf_counter)
    summary = res.to_json()
    summary.update(noise_source=noise.source, noise_detail=noise.detail)
    if summary.get("reading_mm") is not None:
        summary["reading_mm"]["offset_source"] = {
            aid: u[1] for aid, u in zip(ids, used, strict=True) if u is not None
        }
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
                cell_noise,
                state.store,
                state.sampler,
                state.settings.sampler,
                campaign_id,
                int(campaign["robot_id"]),
            )
        )
        known = known_offsets(state, campaign_id, int(campaign["robot_id"]))
        summary, poses = await asyncio.to_thread(_compute, model, body, start, noise, known)
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
