"""The live sensor watch (:mod:`daemon.monitors.watch`): undo an automatic anchor split."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, HTTPException

from daemon.api.deps import CampaignId, State, WriteAuth
from daemon.api.errors import error_responses
from daemon.monitors.watch import NothingToUndo

router = APIRouter(
    tags=["campaigns"],
    dependencies=[WriteAuth],
    responses=error_responses(401, 404, 409, 413, 422),
)


@router.post(
    "/campaigns/{campaign_id}/sensor-moved/undo", summary="Undo the last automatic anchor split"
)
def undo_sensor_moved(state: State, campaign_id: CampaignId) -> dict[str, Any]:
    """The watch took a step in the residuals for a moved sensor and put the samples from
    there on in a new anchor session. This puts them (and auto capture, if it uses the new
    anchor) back in the previous one: ``event_id`` (the ``sensor_moved`` event undone),
    ``anchor`` (now used), ``from_anchor``, ``sample_ids``. 409 when there is nothing to
    undo."""
    if state.watch is None:
        raise HTTPException(409, "the sensor watch is not running")
    try:
        out: dict[str, Any] = state.watch.undo(campaign_id)
    except NothingToUndo as exc:
        raise HTTPException(409, str(exc)) from None
    return out
