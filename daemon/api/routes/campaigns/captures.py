"""A manual capture into a campaign: settled, within the robot's limits, not a repeat."""

from __future__ import annotations

from fastapi import APIRouter, HTTPException, status

from calib.dataset import (
    JOINT_COLUMNS,
    SampleError,
    known_pose_index,
    make_samples,
    validate_joint_limits,
)
from daemon.api.deps import CampaignId, State, WriteAuth
from daemon.api.errors import ApiError, Error, error_responses
from daemon.api.schemas import CaptureRequest
from daemon.sampler.capture import CaptureRejected
from daemon.store import SampleRow

router = APIRouter(tags=["campaigns"], responses=error_responses(400, 401, 413, 422))


@router.post(
    "/campaigns/{campaign_id}/captures",
    status_code=status.HTTP_201_CREATED,
    summary="Manual capture",
    dependencies=[WriteAuth],
    responses={
        **error_responses(404),
        409: {
            "model": Error,
            "description": "Robot moving / not settled, over-range, pose already captured, "
            "joints_deg outside the joint limits of the campaign's robot model, joints_deg "
            "for a robot driver that reports its own angles",
        },
        503: {
            "model": Error,
            "description": "A device is down or stale; names the device and its last error",
        },
    },
)
async def capture(state: State, campaign_id: CampaignId, body: CaptureRequest) -> SampleRow:
    """Waits up to ``sampler.capture_timeout_s`` for the robot and the cable to settle, then
    stores the mean of the settled window and returns the stored sample. With the manual robot
    driver, ``joints_deg`` carries the joint angles [deg]."""
    campaign = state.store.campaign(campaign_id)
    if state.sampler is None:
        raise HTTPException(503, "sampler: not running")
    if body.joints_deg is not None:
        _check_limits(state, int(campaign["robot_id"]), body.joints_deg)
    if not body.repeat:
        _refuse_a_repeat(state, campaign_id, body.joints_deg)
    try:
        sample: SampleRow = await state.sampler.capture(
            campaign_id, anchor=body.anchor, joints_deg=body.joints_deg
        )
    except CaptureRejected as exc:
        raise HTTPException(
            exc.http_status,
            {"reason": exc.reason, "detail": exc.detail, "device": exc.device},
        ) from exc
    except ValueError as exc:  # joints_deg for a robot that reports its own: the cell's state
        raise HTTPException(409, str(exc)) from exc
    return sample


def _refuse_a_repeat(state: State, campaign_id: int, joints_deg: list[float] | None) -> None:
    """409 ``not_new_pose`` when the robot stands at a pose the campaign has captured
    already: auto capture's rule (:func:`calib.dataset.known_pose_index` within the sampler's
    ``auto_new_pose_deg``, every sample of the campaign, excluded ones too), checked on the
    angles sent (manual robot) or the newest paired reading. The page asks the operator and
    sends ``repeat`` to store it anyway."""
    assert state.sampler is not None
    q: list[float] | tuple[float, ...] | None = joints_deg
    if q is None:
        newest = state.sampler.recent_readings(0.0, 1)
        if not newest:
            return  # no reading yet: the capture itself says so
        q = newest[-1].joints_deg
    known = state.store.poses_deg(campaign_id)
    index = known_pose_index(known, q, state.settings.sampler.auto_new_pose_deg)
    if index is None:
        return
    rows = state.store.list_samples(campaign_id, limit=min(index + 1, 10_000))
    which = f"sample {rows[index]['id']}" if index < len(rows) else "a sample"
    detail = (
        f"the robot stands at the pose of {which} (every joint within "
        f"{state.settings.sampler.auto_new_pose_deg:g} deg); move it to a new pose, or "
        "confirm the repeat (repeat: true)"
    )
    raise HTTPException(409, {"reason": "not_new_pose", "detail": detail, "device": None})


def _check_limits(state: State, robot_id: int, joints_deg: list[float]) -> None:
    """The CSV import's checks (finite, within the model's joint limits) on one pose; the
    error names ``joints_deg[j]`` instead of the CSV column ``q{j+1}``. Outside the limits of
    the campaign's robot model is a 409 (a rule of the robot, not of the request's shape)."""
    try:
        pose = make_samples([joints_deg], [0.0])
        validate_joint_limits(pose, state.store.robot_model(robot_id))
    except SampleError as exc:
        j = JOINT_COLUMNS.index(exc.column) if exc.column in JOINT_COLUMNS else None
        loc: tuple[str | int, ...] = ("body", "joints_deg") + (() if j is None else (j,))
        field = "joints_deg" if j is None else f"joints_deg[{j}]"
        # outside the campaign's robot model's limits: CONFLICT, a 409
        raise ApiError(exc.kind, f"{field}: {exc.message}", loc) from exc
