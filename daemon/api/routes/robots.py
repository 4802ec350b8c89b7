"""Robots and their calibrated models."""

from __future__ import annotations

from fastapi import APIRouter

from daemon.api.deps import ReadAuth, RobotId, State
from daemon.api.errors import error_responses
from daemon.api.schemas import CalibratedModelOut, RobotOut

router = APIRouter(
    prefix="/robots",
    tags=["robots"],
    dependencies=[ReadAuth],
    responses=error_responses(401, 404, 413, 422),
)


@router.get("/{robot_id}", summary="One robot and its nominal model")
def get_robot(state: State, robot_id: RobotId) -> RobotOut:
    return state.store.robot(robot_id)


@router.get("/{robot_id}/calibrated-model", summary="The latest accepted calibrated DH table")
def calibrated_model(state: State, robot_id: RobotId) -> CalibratedModelOut:
    """The newest accepted identification's DH table (absolute, per joint), tool point, and
    the job and campaign it came from. 404 until a result has been accepted."""
    return state.store.calibrated_model(robot_id)
