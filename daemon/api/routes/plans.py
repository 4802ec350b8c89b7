"""Pose plans of a campaign: plan (``calib.planning``, off the event loop) and follow progress.

The request and response bodies live here, not in :mod:`daemon.api.schemas`: their defaults
come from :class:`calib.planning.PlanOptions` (one definition), and the plan's summary is
:meth:`calib.planning.PlanResult.to_json` as it is.
"""

from __future__ import annotations

import asyncio
import csv
import io
import time
from typing import Annotated, Any, Literal

import numpy as np
from fastapi import APIRouter, HTTPException, Query, Request, status
from pydantic import ConfigDict, Field
from typing_extensions import TypedDict

from calib.dataset import JOINT_COLUMNS, SampleError, SampleSet
from calib.models import RobotModel
from calib.planning import CSV_COLUMNS, PlanOptions, plan, start_anchors_mm
from calib.programs.formats import DEFAULT_SPEED_PCT
from daemon.api.deps import CampaignId, ReadAuth, State, WriteAuth
from daemon.api.errors import error_responses, unprocessable
from daemon.api.program_download import FORMAT_HELP, DownloadFormat, DwellS, SpeedPct, download
from daemon.api.schemas import MAX_ANCHOR_CHARS, Anchor, StrictBody
from daemon.plan_noise import NoiseEstimate, cell_noise
from daemon.store import MATCH_TOL_DEG, match_poses
from daemon.store.plans import PlanHeader, PlannedPoseRow, PlanRow

router = APIRouter(tags=["plans"], responses=error_responses(401, 404, 413, 422))

_D = PlanOptions()

#: Bounds of a plan request: what one request may ask of the 2-core cell PC.
MAX_POSES = 200
MAX_CANDIDATES = 10_000
MAX_ANCHORS = 4

Coordinate = Annotated[float, Field(ge=-10_000.0, le=10_000.0, allow_inf_nan=False)]
Extension = Annotated[float, Field(ge=0, le=10_000, allow_inf_nan=False)]


class PlanRequest(StrictBody):
    """Options of a plan (see ``cablecal plan --help``; units in the names). The robot is the
    campaign's. Strict: no unknown keys, ``"1"`` is not a number, ``"yes"`` not a boolean;
    pairs and triples are JSON lists of that length."""

    # The schema states the one rule between fields: anchors_mm, unless start_from_samples.
    model_config = ConfigDict(json_schema_extra={"anyOf": [
        {"required": ["anchors_mm"], "properties": {"anchors_mm": {"type": "array"}}},
        {"required": ["start_from_samples"], "properties": {"start_from_samples": {"const": True}}},
    ]})  # fmt: skip

    anchors_mm: Annotated[
        list[Annotated[list[Coordinate], Field(min_length=3, max_length=3)]],
        Field(min_length=1, max_length=MAX_ANCHORS),
    ] | None = Field(
        None,
        description="Anchor guesses [x, y, z] [mm] in the robot base frame, one per sensor "
        "position; default (with start_from_samples): where the campaign's samples put them.",
    )  # fmt: skip
    anchor_ids: Annotated[list[Anchor], Field(min_length=1, max_length=MAX_ANCHORS)] | None = Field(
        None, description="Id per anchor (default A, B, …); an id of the samples means the "
        "sensor has not moved."
    )  # fmt: skip
    n: int = Field(_D.n, ge=1, le=MAX_POSES, description="Poses to plan, all anchors.")
    candidates: int = Field(
        _D.candidates, ge=1, le=MAX_CANDIDATES, description="Random feasible candidate poses."
    )
    seed: int = Field(_D.seed, ge=0, le=2**32 - 1)
    min_z_mm: float = Field(
        _D.min_z_mm, ge=-10_000, le=10_000, allow_inf_nan=False,
        description="Flange and tool point above this z.",
    )  # fmt: skip
    extension_mm: Annotated[list[Extension], Field(min_length=2, max_length=2)] = Field(
        list(_D.extension_mm), description="Allowed cable extension [min, max] [mm]."
    )
    anchor_uncertainty_mm: float = Field(
        _D.anchor_uncertainty_mm, ge=0, le=1000, allow_inf_nan=False,
        description="How far the guess may be off.",
    )  # fmt: skip
    noise_mm: float | None = Field(
        None, gt=0, le=10, allow_inf_nan=False,
        description="1σ noise of one captured length [mm]; default (null): from the cell "
        "(the robot's accepted result, the campaign's captures, the live indicator, else "
        f"{_D.noise_mm}); the summary names it (noise_source).",
    )  # fmt: skip
    joint_speed_deg_s: Annotated[
        list[Annotated[float, Field(gt=0, le=1000, allow_inf_nan=False)]],
        Field(min_length=6, max_length=6),
    ] = Field(list(_D.joint_speed_deg_s), description="Joint speeds for the moves [deg/s].")
    dwell_s: float = Field(
        _D.dwell_s, ge=0, le=600, allow_inf_nan=False,
        description="Settle and read time per pose.",
    )  # fmt: skip
    start_from_samples: bool = Field(
        False, description="Plan more poses on top of the campaign's included samples."
    )

    def options(self, noise_mm: float | None = None) -> PlanOptions:
        """The engine's options (anchor ids set by the caller when taken from samples), with
        ``noise_mm`` when the request gives none (else the engine's default)."""
        noise = self.noise_mm if self.noise_mm is not None else noise_mm
        return PlanOptions(
            n=self.n, candidates=self.candidates, seed=self.seed, min_z_mm=self.min_z_mm,
            extension_mm=(self.extension_mm[0], self.extension_mm[1]),
            anchor_uncertainty_mm=self.anchor_uncertainty_mm,
            noise_mm=_D.noise_mm if noise is None else noise,
            joint_speed_deg_s=tuple(self.joint_speed_deg_s),
            dwell_s=self.dwell_s,
            anchor_ids=None if self.anchor_ids is None else tuple(self.anchor_ids),
        )  # fmt: skip


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
    planned = np.array([[p[c] for c in JOINT_COLUMNS] for p in poses], dtype=np.float64)  # type: ignore[literal-required]
    match = match_poses(planned, [p["anchor"] for p in poses], samples.joints_deg,
                        [str(a) for a in samples.anchor], tol_deg)  # fmt: skip
    out: list[PlannedPose] = []
    for pose, k in zip(poses, match, strict=True):
        done = bool(k >= 0)
        out.append({**pose, "status": "done" if done else "pending",
                    "sample_id": sample_ids[int(k)] if done else None})  # fmt: skip
    n_done = int(np.count_nonzero(match >= 0))
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
    res = plan(model, np.asarray(anchors, dtype=float), opts, start=start, clock=time.perf_counter)
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
    except (ValueError, SampleError, np.linalg.LinAlgError) as exc:
        raise unprocessable(_loc(str(exc)), str(exc)) from exc
    finally:
        request.app.state.planning_campaign = None
    options = body.model_dump(mode="json")
    stored = state.store.save_plan(campaign_id, options, summary, poses)
    return _view(state, stored, MATCH_TOL_DEG)


def _plan_csv(stored: PlanRow) -> str:
    """The stored plan's poses as ``cablecal plan`` writes them (columns ``CSV_COLUMNS``)."""
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(CSV_COLUMNS), lineterminator="\n")
    writer.writeheader()
    writer.writerows([{k: p.get(k) for k in CSV_COLUMNS} for p in stored["poses"]])
    return buf.getvalue()


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
