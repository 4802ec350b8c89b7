"""Compensation: a program's targets corrected with the robot's accepted calibration.

Decoding, validation and the IK of up to :data:`daemon.api.schemas.MAX_TARGETS` targets run
in a worker thread, never on the event loop.
"""

from __future__ import annotations

import asyncio
import math
from typing import Any, Literal

from fastapi import APIRouter, HTTPException, Query, Request, Response
from fastapi.exceptions import RequestValidationError
from pydantic import ValidationError

from calib.programs.formats import DEFAULT_SPEED_PCT
from daemon.api.deps import RobotId, State, WriteAuth
from daemon.api.errors import error_responses, unprocessable
from daemon.api.http.downloads import download_headers
from daemon.api.http.offload import offload
from daemon.api.program_download import FORMAT_HELP, DownloadFormat, DwellS, SpeedPct, download
from daemon.api.schemas import (
    ANY_TARGETS,
    MAX_TARGETS,
    TARGET_LISTS,
    TARGET_MODELS,
    TARGETS_SCHEMA,
)

router = APIRouter(tags=["apply"], responses=error_responses(401, 404, 413, 422))

#: Longest ``tool_mm`` / ``seed_deg`` query value [characters].
MAX_QUERY_CHARS = 200


#: A decimal number as :func:`_numbers` reads it (the exponent bounded: always finite).
_DECIMAL = r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]{1,2})?"


def numbers_pattern(n: int) -> str:
    """The schema's pattern of ``n`` comma-separated numbers (``tool_mm``, ``seed_deg``)."""
    return f"^{_DECIMAL}(?:,{_DECIMAL}){{{n - 1}}}$"


def _numbers(text: str | None, n: int, name: str) -> tuple[float, ...] | None:
    if text is None:
        return None
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise unprocessable(
            ("query", name), f"{name}: expected {n} comma-separated numbers"
        ) from None
    if len(values) != n or not all(math.isfinite(v) for v in values):
        raise unprocessable(("query", name), f"{name}: expected {n} finite comma-separated numbers")
    return values


def _validated(errors: ValidationError) -> RequestValidationError:
    """A pydantic error of the JSON body as the API's 422 (locations under ``body``)."""
    issues = errors.errors(include_input=False, include_url=False)
    return RequestValidationError([{**e, "loc": ("body", *e["loc"])} for e in issues])


def _json_targets_csv(raw: bytes) -> str:
    """A JSON list of target objects (``q1..q6``, or ``x, y, z`` [+ ``rx, ry, rz``]),
    validated strictly (errors name the list index and key), as the CSV text
    :func:`calib.compensate.parse_targets_csv` reads."""
    try:
        items = ANY_TARGETS.validate_json(raw, strict=True)
    except ValidationError as exc:
        raise _validated(exc) from None
    first = set(items[0])
    model = next((m for m in TARGET_MODELS if set(m.model_fields) <= first), None)
    if model is None:
        raise unprocessable(
            ("body", 0), "body[0]: a target needs q1..q6, or x, y, z (+ rx, ry, rz)"
        )
    try:
        targets = TARGET_LISTS[model].validate_python(items)
    except ValidationError as exc:
        raise _validated(exc) from None
    keys = list(model.model_fields)
    lines = [",".join(keys)]
    lines += [",".join(repr(float(getattr(t, k))) for k in keys) for t in targets]
    return "\n".join(lines) + "\n"


def _refuse_outside_limits(rows: list[dict[str, Any]]) -> None:
    """A corrected target outside the robot model's joint limits cannot go into a program: a
    409 naming it (a rule of the robot, as for a capture's joints; the README's conflicts),
    before the program writer's 422 for any other flag."""
    for k, row in enumerate(rows):
        flags = str(row.get("flags") or "").split(";")  # the CSV row's ;-joined flags
        limits = [f for f in flags if f.startswith("outside_limits")]
        if limits:
            raise HTTPException(
                409,
                f"format: target {k + 1}: the corrected joints are outside the robot's joint "
                f"limits ({', '.join(map(str, limits))}); fix or remove it first",
            )


def _compensate(
    state: State, robot_id: int, raw: bytes, is_csv: bool, mode: str, tool: Any, seed: Any
) -> dict[str, Any]:
    """Decode, validate, parse and compensate (in a worker thread); the JSON mapping with the
    corrected CSV under ``csv``."""
    from calib.compensate import (
        CompensateOptions,
        JointTargets,
        compensate,
        default_seed_deg,
        parse_targets_csv,
    )
    from calib.export import model_from_result

    if is_csv:
        try:
            text = raw.decode("utf-8-sig")
        except UnicodeDecodeError as exc:
            raise HTTPException(400, f"body: not UTF-8 ({exc})") from None
    else:
        text = _json_targets_csv(raw)
    result = state.store.accepted_result(robot_id)["result"]
    nominal = state.store.robot_model(robot_id)
    try:
        # x,y,z targets without a seed: the middle of the joint limits picks the IK branch.
        targets = parse_targets_csv(text, seed if seed is not None else default_seed_deg(nominal))
        rows = targets.joints_deg if isinstance(targets, JointTargets) else targets.position_mm
        n = rows.shape[0]
        if n > MAX_TARGETS:
            raise ValueError(f"{n} targets, at most {MAX_TARGETS}")
        options = CompensateOptions(mode=mode, tool_mm=tool or (0.0, 0.0, 0.0))  # type: ignore[arg-type]
        out = compensate(nominal, model_from_result(result, nominal), targets, options)
    except ValueError as exc:
        raise unprocessable(("body",), f"body: {exc}") from exc
    return out.to_json() | {"csv": out.to_csv()}


@router.post(
    "/robots/{robot_id}/compensate",
    summary="Correct a program with the robot's accepted calibration",
    dependencies=[WriteAuth],
    responses={
        200: {"content": {"text/csv": {}, "text/plain": {}}},
        **error_responses(400, 409, 429, 503),
    },
    openapi_extra={
        "requestBody": {
            "required": True,
            "content": {
                "application/json": {"schema": TARGETS_SCHEMA},
                "text/csv": {"schema": {"type": "string"}},
            },
        }
    },
)
async def compensate_targets(
    state: State,
    robot_id: RobotId,
    request: Request,
    mode: Literal["position", "pose"] = Query("position"),
    tool_mm: str | None = Query(
        None,
        max_length=MAX_QUERY_CHARS,
        description="TCP in the flange frame: X,Y,Z [mm].",
        json_schema_extra={"pattern": numbers_pattern(3)},
    ),
    seed_deg: str | None = Query(
        None,
        max_length=MAX_QUERY_CHARS,
        description="q1,…,q6 [deg]: IK branch of x,y,z rows (default: the middle of each "
        "joint's limits).",
        json_schema_extra={"pattern": numbers_pattern(6)},
    ),
    format: DownloadFormat | None = Query(None, description=FORMAT_HELP),
    speed_pct: SpeedPct = DEFAULT_SPEED_PCT,
    dwell_s: DwellS = None,
) -> Any:
    """Body: a CSV (``Content-Type: text/csv``, header ``q1..q6`` [deg] or ``x,y,z`` [mm]
    [+ ``rx,ry,rz`` deg]) or a JSON list of objects with the same keys (strict: numbers only,
    no other keys); at most :data:`MAX_TARGETS` targets and 4 MiB. Returns ``mode, kind,
    tool_mm, note, summary, rows`` (each row: corrected ``q1..q6``, ``residual_mm``,
    ``residual_deg``, ``iterations``, ``flags``), or the corrected CSV when the request
    accepts ``text/csv``. With ``format``, the corrected joint targets as a download: ``csv``,
    or a robot program (``rapid``, ``urscript``, ``krl``, ``fanuc-ls``: each target a joint move
    to a fine stop, then ``dwell_s``; a flagged target is a 422 naming its row). 404 without
    an accepted calibration. Decoding, validation and the IK run in a worker thread."""
    tool = _numbers(tool_mm, 3, "tool_mm")
    seed = _numbers(seed_deg, 6, "seed_deg")
    state.store.accepted_result(robot_id)  # 404 before the body is read
    chunks = [chunk async for chunk in request.stream()]  # the request guard bounds the size
    is_csv = request.headers.get("content-type", "").split(";")[0].strip() == "text/csv"
    raw = b"".join(chunks)

    async def work() -> dict[str, Any]:
        return await asyncio.to_thread(_compensate, state, robot_id, raw, is_csv, mode, tool, seed)

    out = await offload(request, state.gates["check"], work, cancel_on_leave=False)
    csv_text = out.pop("csv")
    if format is not None and format.value != "csv":
        _refuse_outside_limits(out["rows"])
    if format is not None:
        return download(
            csv_text,
            str(format.value),
            stem=f"robot-{robot_id}-compensated",
            model=state.store.robot_model(robot_id),
            what=f"compensated targets of robot {robot_id}",
            speed_pct=speed_pct,
            dwell_s=dwell_s,
            settle_s=state.settings.sampler.settle_s,
        )
    if "text/csv" in request.headers.get("accept", ""):
        return Response(
            csv_text,
            media_type="text/csv",
            headers=download_headers(f"robot-{robot_id}-compensated.csv"),
        )
    return out
