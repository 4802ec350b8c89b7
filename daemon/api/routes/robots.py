"""Robots and their calibrated models."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, HTTPException

from daemon.api.deps import ReadAuth, State

router = APIRouter(prefix="/robots", tags=["robots"], dependencies=[ReadAuth])


@router.get("/{robot_id}", summary="One robot and its nominal model")
def get_robot(state: State, robot_id: int) -> dict[str, Any]:
    robot = state.store.get_robot(robot_id)
    if robot is None:
        raise HTTPException(404, f"robot {robot_id}: not found")
    return dict(robot)


@router.get("/{robot_id}/calibrated-model", summary="The latest accepted calibrated DH table")
def calibrated_model(state: State, robot_id: int) -> dict[str, Any]:
    """The newest accepted identification's DH table (absolute, per joint), tool point, and
    the job and campaign it came from. 404 until a result has been accepted."""
    if state.store.get_robot(robot_id) is None:
        raise HTTPException(404, f"robot {robot_id}: not found")
    model = state.store.latest_calibrated_model(robot_id)
    if model is None:
        raise HTTPException(404, f"robot {robot_id}: no accepted calibration yet")
    return dict(model)
