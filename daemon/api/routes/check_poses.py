"""A robot's drift-check poses: the user's, or the default spread of its calibration's samples."""

from __future__ import annotations

from fastapi import APIRouter

from daemon.api.deps import ReadAuth, RobotId, State, WriteAuth
from daemon.api.errors import error_responses
from daemon.api.schemas import CheckPosesBody
from daemon.holdcheck import check_poses
from daemon.store import CheckPoses

router = APIRouter(tags=["apply"], responses=error_responses(401, 404, 413, 422))


@router.put(
    "/robots/{robot_id}/check-poses",
    summary="Set the drift-check poses",
    dependencies=[WriteAuth],
    responses=error_responses(400),
)
def put_check_poses(state: State, robot_id: RobotId, body: CheckPosesBody) -> CheckPoses:
    """3 to 100 joint vectors of finite numbers [deg]; they replace the default (spread poses
    of the calibration's samples)."""
    return state.store.set_check_poses(robot_id, body.poses_deg)


@router.get(
    "/robots/{robot_id}/check-poses", summary="The drift-check poses", dependencies=[ReadAuth]
)
def get_check_poses(state: State, robot_id: RobotId) -> CheckPoses:
    """The user's poses (``source`` user) or the default (``source`` default: spread poses
    of the accepted calibration's samples; 404 without one)."""
    return check_poses(state.store, robot_id, state.settings.drift.n_poses)
