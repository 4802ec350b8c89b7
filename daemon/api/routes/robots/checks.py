"""Hold checks of a robot: start one, read the history (`daemon.monitors.holdcheck`)."""

from __future__ import annotations

from fastapi import APIRouter, HTTPException, Query, status

from daemon.api.deps import ReadAuth, RobotId, State, WriteAuth
from daemon.api.errors import error_responses
from daemon.monitors.holdcheck import CheckConflict
from daemon.store import CheckRow

router = APIRouter(tags=["apply"], responses=error_responses(401, 404, 413, 422))


@router.post(
    "/robots/{robot_id}/checks",
    status_code=status.HTTP_202_ACCEPTED,
    summary="Start a hold check",
    dependencies=[WriteAuth],
    responses=error_responses(409),
)
async def start_check(state: State, robot_id: RobotId) -> CheckRow:
    """Creates the check campaign and switches auto capture to it (on the event loop, where
    the sampler and the check's task live); the robot must visit the check poses
    (``GET …/check-poses``). Follow it at ``GET /robots/{id}/checks``. 409 while another
    check runs or auto capture is on for a campaign."""
    try:
        return state.hold_check.start_check(robot_id, "manual")  # type: ignore[no-any-return]
    except CheckConflict as exc:
        raise HTTPException(409, str(exc)) from exc
    except ValueError as exc:
        raise HTTPException(409, str(exc)) from exc


@router.get("/robots/{robot_id}/checks", summary="Hold-check history", dependencies=[ReadAuth])
def list_checks(
    state: State, robot_id: RobotId, limit: int = Query(100, ge=1, le=1000)
) -> list[CheckRow]:
    """The newest ``limit`` checks, oldest first: ``status`` running/ok/not_held/failed,
    ``rms_mm``, ``threshold_mm``, ``campaign_id``, ``poses_deg``."""
    state.store.robot(robot_id)
    return state.store.list_checks(robot_id, limit=limit)
