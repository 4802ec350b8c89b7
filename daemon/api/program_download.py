"""Joint targets as a download: CSV, or a robot program (:mod:`calib.programs`).

Used by ``GET /campaigns/{id}/plan?format=`` (the plan) and ``POST
/robots/{id}/compensate?format=`` (the corrected targets). The format names, the speed
default and the dwell rule come from :mod:`calib.programs.formats`; the dwell default from the
running daemon's ``sampler.settle_s``.
"""

from __future__ import annotations

import csv
import io
from enum import Enum
from typing import Annotated

from fastapi import Query, Response

from calib.csvtext import restore_cell
from calib.error_kinds import ErrorKind
from calib.models import RobotModel
from calib.programs.common import SPEED_PCT_RANGE, ProgramError, check_limits, read_targets_csv
from calib.programs.formats import (
    DEFAULT_SPEED_PCT,
    DOWNLOAD_FORMATS,
    SUFFIX,
    TITLE,
    dwell_s_for_settle,
)
from calib.programs.registry import build_program, name_rule
from daemon.api.errors import ApiError
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
    Fanuc find a program by its file name). A target outside ``model``'s limits is a 409, a
    flagged one a 422, each naming the row and joint; an anchor the targets lack a 404, and
    several anchors with none picked a 409 (statuses from
    :data:`daemon.api.errors.STATUS_OF_KIND`)."""
    if fmt == "csv":  # every anchor's poses, as the plan has them
        body, filename = csv_text, f"{stem}.csv"
    else:
        name = name_rule(fmt).from_text(stem if anchor is None else f"{stem}-{anchor}")
        dwell = dwell_s if dwell_s is not None else dwell_s_for_settle(settle_s)
        limits = model.limits_deg().tolist()
        # The status follows the check that failed, never the message's words: the targets
        # of the anchor (an anchor the plan lacks: NOT_FOUND; a plan that needs one picked:
        # CONFLICT; both the campaign's state), then the robot model's limits (CONFLICT, a rule
        # of the robot, as for a capture's joints_deg), then the program itself (INVALID).
        try:
            targets = read_targets_csv(csv_text, what, anchor)
        except ProgramError as exc:
            kind = _anchor_kind(csv_text, anchor)
            detail = str(exc) if kind is not ErrorKind.INVALID else f"format: {exc}"
            raise ApiError(kind, detail, ("query", "format")) from exc
        try:
            check_limits(targets.joints_deg, limits, targets.rows)
        except ProgramError as exc:
            raise ApiError(ErrorKind.CONFLICT, f"format: {exc}") from exc
        try:
            _, body = build_program(
                csv_text,
                fmt=fmt,
                name=name,
                robot_name=model.name,
                limits_deg=limits,
                speed_pct=speed_pct,
                dwell_s=dwell,
                what=what,
                source=what,
                anchor=anchor,
            )
        except ProgramError as exc:
            raise ApiError(ErrorKind.INVALID, f"format: {exc}", ("query", "format")) from exc
        filename = name + SUFFIX[fmt]
    return Response(
        body,
        media_type=MEDIA_TYPE[fmt],
        headers=download_headers(filename),
    )


def _anchor_kind(csv_text: str, anchor: str | None) -> ErrorKind:
    """What the targets' anchors say of a refused read: ``anchor`` is not among them
    (NOT_FOUND), none was picked among several (CONFLICT), else the file's form (INVALID)."""
    reader = csv.reader(io.StringIO(csv_text))
    names = [c.strip().lower() for c in next(reader, [])]
    if "anchor" not in names:
        return ErrorKind.INVALID
    col = names.index("anchor")
    rows = [r for r in reader if any(c.strip() for c in r)]
    seen = {restore_cell(r[col].strip()) if col < len(r) else "" for r in rows}
    if anchor is not None and anchor not in seen:
        return ErrorKind.NOT_FOUND
    if anchor is None and len(seen) > 1:
        return ErrorKind.CONFLICT
    return ErrorKind.INVALID
