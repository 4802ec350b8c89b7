"""Applying and watching a calibration: compensate, export, verify, check poses, drift checks.

The heavy work (IK of up to :data:`MAX_TARGETS` targets, a verification) runs in a worker
thread, never on the event loop.
"""

from __future__ import annotations

import asyncio
import math
from typing import Annotated, Any, Literal

from fastapi import APIRouter, HTTPException, Query, Request, Response, status
from fastapi.exceptions import RequestValidationError
from pydantic import Field, TypeAdapter, ValidationError

from calib.programs.formats import DEFAULT_SPEED_PCT
from daemon.api.deps import MAX_ID, JobId, ReadAuth, RobotId, State, WriteAuth
from daemon.api.downloads import download_headers
from daemon.api.errors import error_responses, unprocessable
from daemon.api.program_download import FORMAT_HELP, DownloadFormat, DwellS, SpeedPct, download
from daemon.api.schemas import StrictBody
from daemon.holdcheck import CheckConflict, check_poses
from daemon.store import CheckPoses, CheckRow

router = APIRouter(tags=["apply"], responses=error_responses(401, 404, 413, 422))

#: Most targets one compensation request may carry (the body is bounded by the request
#: guard: :data:`daemon.api.guard.MAX_COMPENSATE_BYTES`).
MAX_TARGETS = 10_000
#: Longest ``tool_mm`` / ``seed_deg`` query value [characters].
MAX_QUERY_CHARS = 200

EXPORT_MEDIA_TYPES = {
    "toml": "application/toml",
    "urdf": "application/xml",
    "json": "application/json",
}

JointDeg = Annotated[float, Field(ge=-3600.0, le=3600.0, allow_inf_nan=False)]
LengthMm = Annotated[float, Field(ge=-100_000.0, le=100_000.0, allow_inf_nan=False)]


class JointTarget(StrictBody):
    """A target as joint angles q1..q6 [deg]."""

    q1: JointDeg
    q2: JointDeg
    q3: JointDeg
    q4: JointDeg
    q5: JointDeg
    q6: JointDeg


class PositionTarget(StrictBody):
    """A target as a TCP position x, y, z [mm] in the robot base frame."""

    x: LengthMm
    y: LengthMm
    z: LengthMm


class PoseTarget(PositionTarget):
    """A target as a TCP position [mm] and orientation rx, ry, rz [deg]."""

    rx: JointDeg
    ry: JointDeg
    rz: JointDeg


def _targets(model: type[StrictBody]) -> Any:
    return Annotated[list[model], Field(min_length=1, max_length=MAX_TARGETS)]  # type: ignore[valid-type]


_TARGET_MODELS: tuple[type[StrictBody], ...] = (JointTarget, PoseTarget, PositionTarget)
_TARGET_LISTS = {m: TypeAdapter(_targets(m)) for m in _TARGET_MODELS}
_ANY_TARGETS: TypeAdapter[Any] = TypeAdapter(
    Annotated[list[dict[str, Any]], Field(min_length=1, max_length=MAX_TARGETS)]
)
#: The JSON request body as documented: one of the three target lists.
TARGETS_SCHEMA = {"anyOf": [TypeAdapter(_targets(m)).json_schema() for m in _TARGET_MODELS]}


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
        items = _ANY_TARGETS.validate_json(raw, strict=True)
    except ValidationError as exc:
        raise _validated(exc) from None
    first = set(items[0])
    model = next((m for m in _TARGET_MODELS if set(m.model_fields) <= first), None)
    if model is None:
        raise unprocessable(
            ("body", 0), "body[0]: a target needs q1..q6, or x, y, z (+ rx, ry, rz)"
        )
    try:
        targets = _TARGET_LISTS[model].validate_python(items)
    except ValidationError as exc:
        raise _validated(exc) from None
    keys = list(model.model_fields)
    lines = [",".join(keys)]
    lines += [",".join(repr(float(getattr(t, k))) for k in keys) for t in targets]
    return "\n".join(lines) + "\n"


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
    responses={200: {"content": {"text/csv": {}, "text/plain": {}}}, **error_responses(400)},
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
    out = await asyncio.to_thread(
        _compensate, state, robot_id, b"".join(chunks), is_csv, mode, tool, seed
    )
    csv_text = out.pop("csv")
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


def export_response(state: State, robot_id: int, fmt: str) -> Response:
    """The accepted calibration as a model file (``toml``, ``json``) or a URDF, with its media
    type and a download filename ``<robot>-calibrated.<ext>``."""
    from calib.export import export_result

    result = state.store.accepted_result(robot_id)["result"]
    nominal = state.store.robot_model(robot_id)
    try:
        text = export_result(result, fmt, nominal)
    except ValueError as exc:
        raise HTTPException(409, f"robot {robot_id}: the accepted result: {exc}") from exc
    name = f"{nominal.name}-calibrated.{fmt}"
    return Response(text, media_type=EXPORT_MEDIA_TYPES[fmt], headers=download_headers(name))


class VerifyRequest(StrictBody):
    """Verify an identification's result on another campaign."""

    campaign_id: int = Field(ge=1, le=MAX_ID, description="The campaign whose samples to predict")
    refit_anchor: bool = Field(False, description="Fit the anchor and zero offset first")


@router.post(
    "/identifications/{job_id}/verify",
    summary="Predict another campaign's lengths from a result",
    dependencies=[WriteAuth],
    responses=error_responses(400, 409),
)
async def verify_result(state: State, job_id: JobId, body: VerifyRequest) -> dict[str, Any]:
    """RMSE, MAE, STD, MAX of ``measured − predicted`` over the campaign's included samples
    and the per-pose residuals (``calib.verify``); ``refit_anchor`` fits the anchor P0 and
    zero offset first (a moved sensor). 409 if the job has no result yet."""
    from calib.verify import VerifyOptions, verify

    state.store.job(job_id)
    result = state.store.get_result_for_job(job_id)
    if result is None:
        raise HTTPException(409, f"identification {job_id}: has no result")
    samples, _ = state.store.sample_set(body.campaign_id)
    if len(samples) == 0:
        raise unprocessable(
            ("body", "campaign_id"), f"campaign_id: campaign {body.campaign_id} has no samples"
        )
    try:
        out = await asyncio.to_thread(verify, result["result"], samples,
                                      VerifyOptions(refit_anchor=body.refit_anchor))  # fmt: skip
    except (ValueError, KeyError) as exc:
        raise unprocessable(("body",), f"campaign {body.campaign_id}: {exc}") from exc
    return out.to_json()


class CheckPosesBody(StrictBody):
    """A robot's check poses [deg]."""

    poses_deg: Annotated[
        list[Annotated[list[JointDeg], Field(min_length=6, max_length=6)]],
        Field(min_length=3, max_length=100),
    ]


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


@router.post(
    "/robots/{robot_id}/checks",
    status_code=status.HTTP_202_ACCEPTED,
    summary="Start a drift check",
    dependencies=[WriteAuth],
    responses=error_responses(409),
)
async def start_check(state: State, robot_id: RobotId) -> CheckRow:
    """Creates the check campaign and switches auto capture to it (on the event loop, where
    the sampler and the check's task live); the robot must visit the check poses
    (``GET …/check-poses``). Follow it at ``GET /robots/{id}/checks``. 409 while another
    check runs or auto capture is on for a campaign."""
    try:
        return state.drift.start_check(robot_id, "manual")  # type: ignore[no-any-return]
    except CheckConflict as exc:
        raise HTTPException(409, str(exc)) from exc
    except ValueError as exc:
        raise HTTPException(409, str(exc)) from exc


@router.get("/robots/{robot_id}/checks", summary="Drift-check history", dependencies=[ReadAuth])
def list_checks(
    state: State, robot_id: RobotId, limit: int = Query(100, ge=1, le=1000)
) -> list[CheckRow]:
    """The newest ``limit`` checks, oldest first: ``status`` running/ok/drift/failed,
    ``rms_mm``, ``threshold_mm``, ``campaign_id``, ``poses_deg``."""
    state.store.robot(robot_id)
    return state.store.list_checks(robot_id, limit=limit)
