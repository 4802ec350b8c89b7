"""A robot's hold-check poses: the user's, or the default spread of its calibration's samples;
as JSON, or as a download for the robot (CSV or a robot program, the plan's formats)."""

from __future__ import annotations

import csv
import io
from typing import Any

from fastapi import APIRouter, HTTPException, Query, status

from calib.dataset import JOINT_COLUMNS
from calib.programs.common import ProgramError, check_limits
from calib.programs.formats import DEFAULT_SPEED_PCT
from daemon.api.deps import ReadAuth, RobotId, State, WriteAuth
from daemon.api.errors import error_responses, unprocessable
from daemon.api.program_download import FORMAT_HELP, DownloadFormat, DwellS, SpeedPct, download
from daemon.api.schemas import CheckPosesBody
from daemon.monitors.holdcheck import check_poses
from daemon.store import CheckPoses

router = APIRouter(tags=["apply"], responses=error_responses(401, 404, 413, 422))


@router.put(
    "/robots/{robot_id}/check-poses",
    summary="Set the hold-check poses",
    dependencies=[WriteAuth],
    responses=error_responses(400),
)
def put_check_poses(state: State, robot_id: RobotId, body: CheckPosesBody) -> CheckPoses:
    """3 to 100 joint vectors of finite numbers [deg], each within the robot model's joint
    limits (a 422 naming the pose and joint; nothing stored); they replace the default
    (spread poses of the calibration's samples)."""
    limits = state.store.robot_model(robot_id).limits_deg().tolist()
    try:
        check_limits(body.poses_deg, limits)
    except ProgramError as exc:
        raise unprocessable(["body", "poses_deg"], f"poses_deg: {exc} (row = pose)") from None
    return state.store.set_check_poses(robot_id, body.poses_deg)


def _poses_csv(poses_deg: list[list[float]]) -> str:
    """The check poses as joint targets: ``pose`` (1-based) and ``q1..q6`` [deg]."""
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(["pose", *JOINT_COLUMNS])
    writer.writerows([[i + 1, *(f"{v:.6f}" for v in q)] for i, q in enumerate(poses_deg)])
    return buf.getvalue()


@router.get(
    "/robots/{robot_id}/check-poses",
    summary="The hold-check poses",
    dependencies=[ReadAuth],
    response_model=CheckPoses,
    responses={
        200: {"content": {"text/csv": {}, "text/plain": {}}},
        **error_responses(409),
    },
)
def get_check_poses(
    state: State,
    robot_id: RobotId,
    format: DownloadFormat | None = Query(None, description=FORMAT_HELP),
    speed_pct: SpeedPct = DEFAULT_SPEED_PCT,
    dwell_s: DwellS = None,
) -> Any:
    """The user's poses (``source`` user) or the default (``source`` default: spread poses
    of the accepted calibration's samples; 404 without one).

    With ``format``, the poses as a download for the robot, as the plan's (``GET
    /campaigns/{id}/plan?format=``, the same program building): ``csv`` or a robot program
    (each pose a joint move to a fine stop, then a dwell of ``dwell_s``, default from the
    sampler's ``settle_s``); a hold check's auto capture records each pose the robot
    stops at."""
    poses = check_poses(state.store, robot_id, state.settings.hold_check.n_poses)
    if format is None:
        return poses
    model = state.store.robot_model(robot_id)
    try:  # poses stored before PUT checked their limits: a conflict, named by pose (not CSV row)
        check_limits(poses["poses_deg"], model.limits_deg().tolist())
    except ProgramError as exc:
        raise HTTPException(
            status.HTTP_409_CONFLICT,
            f"the robot's check poses cannot be written as a program: {exc} (row = pose); "
            "set them again (PUT /robots/{robot_id}/check-poses)",
        ) from None
    return download(
        _poses_csv(poses["poses_deg"]),
        str(format.value),
        stem=f"robot-{robot_id}-check-poses",
        model=model,
        what=f"hold-check poses of robot {state.store.robot(robot_id)['name']} "
        f"(robot {robot_id}, {poses['source']} poses)",
        speed_pct=speed_pct,
        dwell_s=dwell_s,
        settle_s=state.settings.sampler.settle_s,
    )
