"""Joint targets as a download: CSV, or a robot program (:mod:`calib.programs`).

Used by ``GET /campaigns/{id}/plan?format=`` (the plan) and ``POST
/robots/{id}/compensate?format=`` (the corrected targets). The format names, the speed
default and the dwell rule come from :mod:`calib.programs.formats`; the dwell default from the
running daemon's ``sampler.settle_s``.
"""

from __future__ import annotations

from enum import Enum
from typing import Annotated

from fastapi import HTTPException, Query, Response

from calib.models import RobotModel
from calib.programs.common import SPEED_PCT_RANGE, ProgramError
from calib.programs.formats import (
    DEFAULT_SPEED_PCT,
    DOWNLOAD_FORMATS,
    SUFFIX,
    TITLE,
    dwell_s_for_settle,
)
from calib.programs.registry import build_program, name_rule
from daemon.api.errors import unprocessable
from daemon.api.http.downloads import download_headers

#: ``format``: the REST enum, from the one list of formats.
DownloadFormat = Enum(  # type: ignore[misc]
    "DownloadFormat", {f.replace("-", "_"): f for f in DOWNLOAD_FORMATS}, type=str
)

FORMAT_HELP = "Download as: " + ", ".join(f"{f} ({TITLE[f]})" for f in DOWNLOAD_FORMATS)

SpeedPct = Annotated[
    float,
    Query(
        ge=SPEED_PCT_RANGE[0],
        le=SPEED_PCT_RANGE[1],
        allow_inf_nan=False,
        description="Program formats: joint speed [% of the robot's maximum].",
    ),
]
DwellS = Annotated[
    float | None,
    Query(
        ge=0,
        le=600,
        allow_inf_nan=False,
        description="Program formats: wait at each target [s]; default from the sampler's "
        "settle_s.",
    ),
]

#: Media type per format (programs are plain text).
MEDIA_TYPE = {f: "text/csv" if f == "csv" else "text/plain" for f in DOWNLOAD_FORMATS}


def download(
    csv_text: str,
    fmt: str,
    *,
    stem: str,
    model: RobotModel,
    what: str,
    speed_pct: float = DEFAULT_SPEED_PCT,
    dwell_s: float | None,
    settle_s: float,
    anchor: str | None = None,
) -> Response:
    """``csv_text`` (joint targets with ``q1..q6``) as an attachment in format ``fmt``. The
    program is named from ``stem`` by the controller's rules, and so is the file (KRL and
    Fanuc find a program by its file name). A target outside ``model``'s limits or flagged
    is a 422 naming the row and joint."""
    if fmt == "csv":  # every anchor's poses, as the plan has them
        body, filename = csv_text, f"{stem}.csv"
    else:
        name = name_rule(fmt).from_text(stem if anchor is None else f"{stem}-{anchor}")
        dwell = dwell_s if dwell_s is not None else dwell_s_for_settle(settle_s)
        try:
            _, body = build_program(
                csv_text,
                fmt=fmt,
                name=name,
                robot_name=model.name,
                limits_deg=model.limits_deg().tolist(),
                speed_pct=speed_pct,
                dwell_s=dwell,
                what=what,
                source=what,
                anchor=anchor,
            )
        except ProgramError as exc:
            message = str(exc)
            # The plan's anchors are the campaign's state, not the request's form: an anchor
            # the plan lacks is a 404, a plan that needs one picked a 409 (both name it).
            if message.startswith("anchor:"):
                raise HTTPException(404 if " is not in " in message else 409, message) from exc
            # Targets outside the robot model's limits: a rule of the robot, not of the
            # request's form (as for a capture's joints_deg): 409, naming row and joint.
            if "outside the joint limits" in message:
                raise HTTPException(409, f"format: {message}") from exc
            raise unprocessable(("query", "format"), f"format: {exc}") from exc
        filename = name + SUFFIX[fmt]
    return Response(
        body,
        media_type=MEDIA_TYPE[fmt],
        headers=download_headers(filename),
    )
