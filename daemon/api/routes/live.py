"""Recent paired readings for the operator page's live cable-length trace."""

from __future__ import annotations

import math
import time
from typing import Annotated

from fastapi import APIRouter, Query
from typing_extensions import TypedDict

from daemon.api.deps import ReadAuth, State
from daemon.api.errors import error_responses

router = APIRouter(tags=["system"], responses=error_responses(401, 413, 422))

#: Most readings one answer carries (the sampler's ring buffer spans ``history_s``).
MAX_READINGS = 2000


class Readings(TypedDict):
    """Columns of recent paired readings, oldest first (all lists of the same length n).

    ``t_wall_s``: the length reading's Unix time [s]; ``length_mm``: cable length [mm], null
    when the indicator was over range; ``joints_deg``: n rows of 6 joint angles [deg];
    ``now_wall_s``: the server's Unix time at the answer [s] (to align the clocks)."""

    t_wall_s: list[float]
    length_mm: list[float | None]
    joints_deg: list[list[float]]
    now_wall_s: float


@router.get("/readings", summary="Recent readings (live trace)", dependencies=[ReadAuth])
async def recent_readings(
    state: State,
    since_wall_s: Annotated[
        float, Query(ge=0, description="Only readings stamped later than this Unix time [s].")
    ] = 0.0,
    limit: Annotated[int, Query(ge=1, le=MAX_READINGS, description="At most this many.")] = 500,
) -> Readings:
    """The paired readings the sampler still holds (its ring buffer, the last
    ``sampler.history_s`` seconds), newer than ``since_wall_s``, at most the newest
    ``limit``. Poll with the last ``t_wall_s`` seen to follow the cable length live."""
    rows = [] if state.sampler is None else state.sampler.recent_readings(since_wall_s, limit)
    return {
        "t_wall_s": [r.t_wall for r in rows],
        "length_mm": [None if math.isnan(r.length_mm) else r.length_mm for r in rows],
        "joints_deg": [list(r.joints_deg) for r in rows],
        "now_wall_s": time.time(),
    }
