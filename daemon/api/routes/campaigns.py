"""Campaigns, captures and samples."""

from __future__ import annotations

import numpy as np
from fastapi import APIRouter, HTTPException, Query, Request, Response, status

from calib.dataset import (
    JOINT_COLUMNS,
    SampleError,
    make_samples,
    parse_samples_csv,
    validate_joint_limits,
)
from calib.models import ModelError, builtin_model, model_from_mapping
from daemon.api.deps import ReadAuth, State, WriteAuth
from daemon.api.schemas import (
    AutoCapture,
    CampaignCreate,
    CampaignOut,
    CaptureRequest,
    ImportResult,
    SampleOut,
    SamplePatch,
)
from daemon.capture import CaptureRejected

router = APIRouter(tags=["campaigns"])

#: Largest CSV upload [bytes] (2000 poses are about 150 kB).
MAX_IMPORT_BYTES = 20 * 1024 * 1024


@router.post(
    "/campaigns",
    status_code=status.HTTP_201_CREATED,
    summary="Create a campaign",
    dependencies=[WriteAuth],
)
def create_campaign(state: State, body: CampaignCreate) -> CampaignOut:
    """``robot_model`` is a built-in name or an uploaded model mapping; returns the campaign
    with its ``id`` and ``robot_id``."""
    if isinstance(body.robot_model, str):
        try:
            builtin_model(body.robot_model)
        except (KeyError, ValueError) as exc:
            raise HTTPException(
                422, f"robot_model: unknown built-in model {body.robot_model!r} ({exc})"
            ) from exc
        robot = state.store.ensure_builtin_robot(body.robot_model)
    else:
        try:
            model = model_from_mapping(body.robot_model)
        except ModelError as exc:
            raise HTTPException(422, f"robot_model.{exc}") from exc
        robot = state.store.add_robot(model, source="uploaded")
    return state.store.create_campaign(body.name, int(robot["id"]), body.notes)


@router.get("/campaigns", summary="List campaigns", dependencies=[ReadAuth])
def list_campaigns(state: State) -> list[CampaignOut]:
    return state.store.list_campaigns()


@router.get("/campaigns/{campaign_id}", summary="One campaign", dependencies=[ReadAuth])
def get_campaign(state: State, campaign_id: int) -> CampaignOut:
    return state.store.campaign(campaign_id)


@router.post(
    "/campaigns/{campaign_id}/captures",
    status_code=status.HTTP_201_CREATED,
    summary="Manual capture",
    dependencies=[WriteAuth],
    responses={
        409: {"description": "Robot moving / not settled, over-range, pose already captured"},
        503: {"description": "A device is down or stale; names the device and its last error"},
    },
)
async def capture(state: State, campaign_id: int, body: CaptureRequest) -> SampleOut:
    """Waits up to ``sampler.capture_timeout_s`` for the robot and the cable to settle, then
    stores the mean of the settled window and returns the stored sample. With the manual robot
    driver, ``joints_deg`` carries the joint angles [deg]."""
    campaign = state.store.campaign(campaign_id)
    if state.sampler is None:
        raise HTTPException(503, "sampler: not running")
    if body.joints_deg is not None:
        _check_limits(state, int(campaign["robot_id"]), body.joints_deg)
    try:
        sample: SampleOut = await state.sampler.capture(
            campaign_id, anchor=body.anchor, joints_deg=body.joints_deg
        )
    except CaptureRejected as exc:
        raise HTTPException(
            exc.http_status,
            {"reason": exc.reason, "detail": exc.detail, "device": exc.device},
        ) from exc
    except ValueError as exc:
        raise HTTPException(422, str(exc)) from exc
    return sample


def _check_limits(state: State, robot_id: int, joints_deg: list[float]) -> None:
    """The CSV import's checks (finite, within the model's joint limits) on one pose; the
    error names ``joints_deg[j]`` instead of the CSV column ``q{j+1}``."""
    try:
        pose = make_samples(np.asarray([joints_deg], dtype=float), np.zeros(1))
        validate_joint_limits(pose, state.store.robot_model(robot_id))
    except SampleError as exc:
        j = JOINT_COLUMNS.index(exc.column) if exc.column in JOINT_COLUMNS else None
        field = "joints_deg" if j is None else f"joints_deg[{j}]"
        message = str(exc).split(": ", 1)[-1]
        raise HTTPException(422, f"{field}: {message}") from exc


@router.put(
    "/campaigns/{campaign_id}/auto-capture",
    summary="Auto capture on or off",
    dependencies=[WriteAuth],
)
def auto_capture(state: State, campaign_id: int, body: AutoCapture) -> CampaignOut:
    """On: the sampler captures once at each new settled pose, for this campaign only (it
    switches off any other campaign). The setting survives a daemon restart."""
    state.store.campaign(campaign_id)  # 404 before the sampler is touched
    if body.enabled:
        if state.sampler is None:
            raise HTTPException(503, "sampler: not running")
        for other in state.store.auto_capture_campaigns():
            if int(other["id"]) != campaign_id:
                state.store.set_auto_capture(int(other["id"]), False)
        state.sampler.set_auto(
            campaign_id, anchor=body.anchor, known_poses_deg=state.store.poses_deg(campaign_id)
        )
    elif state.sampler is not None and state.sampler.auto_campaign_id == campaign_id:
        state.sampler.set_auto(None)
    return state.store.set_auto_capture(campaign_id, body.enabled, body.anchor)


@router.get(
    "/campaigns/{campaign_id}/samples",
    summary="Samples as JSON, or CSV with ?format=csv",
    dependencies=[ReadAuth],
    responses={200: {"content": {"text/csv": {}}}},
    response_model=list[SampleOut],
)
def list_samples(
    state: State,
    campaign_id: int,
    format: str = Query("json", pattern="^(json|csv)$", description="json or csv"),
) -> list[SampleOut] | Response:
    """JSON: every sample with its std, count, timestamps and excluded flag. CSV: the included
    samples in the format ``cablecal identify`` reads."""
    if format == "csv":
        return Response(
            state.store.export_csv(campaign_id),
            media_type="text/csv",
            headers={"Content-Disposition": f'attachment; filename="campaign-{campaign_id}.csv"'},
        )
    return state.store.list_samples(campaign_id)


@router.post(
    "/campaigns/{campaign_id}/samples/import",
    status_code=status.HTTP_201_CREATED,
    summary="Import samples from CSV",
    dependencies=[WriteAuth],
    openapi_extra={
        "requestBody": {"content": {"text/csv": {"schema": {"type": "string"}}}, "required": True}
    },
)
async def import_samples(state: State, campaign_id: int, request: Request) -> ImportResult:
    """The request body is the CSV text (``Content-Type: text/csv``): header q1..q6 [deg] and
    L [mm], optional ``anchor``. All or nothing: an error gives 400 naming the row (file line,
    header = 1) and column, and nothing of the import is stored."""
    state.store.campaign(campaign_id)  # 404 before the body is read
    raw = await request.body()
    if len(raw) > MAX_IMPORT_BYTES:
        raise HTTPException(413, f"body: larger than {MAX_IMPORT_BYTES} bytes")
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise HTTPException(
            400, {"row": None, "column": None, "message": f"not UTF-8: {exc}"}
        ) from exc
    try:
        samples = parse_samples_csv(text)  # header, numbers, NaN, sensor range: row and column
        ids = state.store.import_samples(campaign_id, samples)  # and the robot's joint limits
    except SampleError as exc:
        raise HTTPException(
            400, {"row": exc.row, "column": exc.column, "message": str(exc)}
        ) from exc
    return {"imported": len(ids), "sample_ids": ids}


@router.patch("/samples/{sample_id}", summary="Exclude or include", dependencies=[WriteAuth])
def patch_sample(state: State, sample_id: int, body: SamplePatch) -> SampleOut:
    return state.store.set_excluded(sample_id, body.excluded, body.reason)
