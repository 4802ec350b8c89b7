"""Robots and their calibrated models."""

from __future__ import annotations

from typing import Any, Literal

from fastapi import APIRouter, Query

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


@router.get(
    "/{robot_id}/calibrated-model",
    summary="The latest accepted calibrated DH table, or a model file",
    response_model=CalibratedModelOut,
)
def calibrated_model(
    state: State,
    robot_id: RobotId,
    format: Literal["toml", "urdf", "json"] | None = Query(
        None, description="A model file (toml, json: for --robot) or a URDF, as a download."
    ),
) -> Any:
    """The newest accepted identification's DH table (absolute, per joint), tool point, and
    the job and campaign it came from. 404 until a result has been accepted. With
    ``format``: the model file (``application/toml``, ``application/json``,
    ``application/xml``) named ``<robot>-calibrated.<format>``."""
    if format is not None:
        from daemon.api.routes.apply import export_response

        return export_response(state, robot_id, format)
    return state.store.calibrated_model(robot_id)
