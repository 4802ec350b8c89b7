"""Applying and watching a calibration: compensate, export, verify, check poses, drift checks.

The heavy work (IK of up to :data:`MAX_TARGETS` targets, a verification) runs in a worker
thread, never on the event loop.
"""

from __future__ import annotations

import asyncio
import json
import math
from typing import Annotated, Any, Literal

from fastapi import APIRouter, HTTPException, Query, Request, Response, status
from pydantic import BaseModel, ConfigDict, Field

from daemon.api.deps import ReadAuth, State, WriteAuth
from daemon.drift import CheckConflict, check_poses
from daemon.store import CheckPoses, CheckRow

router = APIRouter(tags=["apply"])

#: Most targets one compensation request may carry.
MAX_TARGETS = 10_000
#: Largest compensation body [bytes] (10 000 Cartesian pose rows are about 1 MB).
MAX_BODY_BYTES = 4 * 1024 * 1024

EXPORT_MEDIA_TYPES = {
    "toml": "application/toml",
    "urdf": "application/xml",
    "json": "application/json",
}
_TARGET_KEYS = (("q1", "q2", "q3", "q4", "q5", "q6"), ("x", "y", "z", "rx", "ry", "rz"),
                ("x", "y", "z"))  # fmt: skip


def _numbers(text: str | None, n: int, name: str) -> tuple[float, ...] | None:
    if text is None:
        return None
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise HTTPException(422, f"{name}: expected {n} comma-separated numbers") from None
    if len(values) != n or not all(math.isfinite(v) for v in values):
        raise HTTPException(422, f"{name}: expected {n} finite comma-separated numbers")
    return values


def _json_targets_csv(items: Any) -> str:
    """A JSON list of target objects (``q1..q6``, or ``x, y, z`` [+ ``rx, ry, rz``]) as the
    CSV text :func:`calib.compensate.parse_targets_csv` reads (errors name the list index)."""
    if not isinstance(items, list) or not items:
        raise HTTPException(422, "body: expected a non-empty JSON list of targets")
    if len(items) > MAX_TARGETS:
        raise HTTPException(422, f"body: {len(items)} targets, at most {MAX_TARGETS}")
    first = items[0]
    keys = next((k for k in _TARGET_KEYS if isinstance(first, dict) and set(k) <= set(first)),
                None)  # fmt: skip
    if keys is None:
        raise HTTPException(422, "body[0]: a target needs q1..q6, or x, y, z (+ rx, ry, rz)")
    lines = [",".join(keys)]
    for i, item in enumerate(items):
        if not isinstance(item, dict):
            raise HTTPException(422, f"body[{i}]: expected an object")
        row = []
        for k in keys:
            v = item.get(k)
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
                raise HTTPException(422, f"body[{i}].{k}: expected a finite number, got {v!r}")
            row.append(repr(float(v)))
        lines.append(",".join(row))
    return "\n".join(lines) + "\n"


def _compensate(
    state: State, robot_id: int, text: str, mode: str, tool: Any, seed: Any
) -> dict[str, Any] | str:
    """Parse and compensate (in a worker thread); the JSON mapping, or 422 text."""
    from calib.compensate import CompensateOptions, JointTargets, compensate, parse_targets_csv
    from calib.export import model_from_result

    result = state.store.accepted_result(robot_id)["result"]
    nominal = state.store.robot_model(robot_id)
    try:
        targets = parse_targets_csv(text, seed)
        rows = targets.joints_deg if isinstance(targets, JointTargets) else targets.position_mm
        n = rows.shape[0]
        if n > MAX_TARGETS:
            return f"body: {n} targets, at most {MAX_TARGETS}"
        options = CompensateOptions(mode=mode, tool_mm=tool or (0.0, 0.0, 0.0))  # type: ignore[arg-type]
        out = compensate(nominal, model_from_result(result, nominal), targets, options)
    except ValueError as exc:
        return f"body: {exc}"
    return out.to_json() | {"csv": out.to_csv()}


@router.post(
    "/robots/{robot_id}/compensate",
    summary="Correct a program with the robot's accepted calibration",
    dependencies=[WriteAuth],
)
async def compensate_targets(
    state: State,
    robot_id: int,
    request: Request,
    mode: Literal["position", "pose"] = Query("position"),
    tool_mm: str | None = Query(None, description="TCP in the flange frame: X,Y,Z [mm]."),
    seed_deg: str | None = Query(None, description="q1,…,q6 [deg]: IK branch of x,y,z rows."),
) -> Any:
    """Body: a CSV (``Content-Type: text/csv``, header ``q1..q6`` [deg] or ``x,y,z`` [mm]
    [+ ``rx,ry,rz`` deg]) or a JSON list of objects with the same keys; at most
    :data:`MAX_TARGETS` targets. Returns ``mode, kind, tool_mm, note, summary, rows`` (each
    row: corrected ``q1..q6``, ``residual_mm``, ``residual_deg``, ``iterations``, ``flags``),
    or the corrected CSV when the request accepts ``text/csv``. 404 without an accepted
    calibration."""
    tool = _numbers(tool_mm, 3, "tool_mm")
    seed = _numbers(seed_deg, 6, "seed_deg")
    body = await request.body()
    if len(body) > MAX_BODY_BYTES:
        raise HTTPException(413, f"body: {len(body)} bytes, at most {MAX_BODY_BYTES}")
    state.store.accepted_result(robot_id)  # 404 before any parsing
    if request.headers.get("content-type", "").split(";")[0].strip() == "text/csv":
        text = body.decode("utf-8-sig", errors="replace")
    else:
        try:
            items = json.loads(body)
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise HTTPException(422, f"body: not JSON ({exc}); send text/csv for CSV") from None
        text = _json_targets_csv(items)
    out = await asyncio.to_thread(_compensate, state, robot_id, text, mode, tool, seed)
    if isinstance(out, str):
        raise HTTPException(422, out)
    csv_text = out.pop("csv")
    if "text/csv" in request.headers.get("accept", ""):
        return Response(
            csv_text,
            media_type="text/csv",
            headers={
                "Content-Disposition": f'attachment; filename="robot-{robot_id}-compensated.csv"'
            },
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
    return Response(text, media_type=EXPORT_MEDIA_TYPES[fmt],
                    headers={"Content-Disposition": f'attachment; filename="{name}"'})  # fmt: skip


class VerifyRequest(BaseModel):
    """Verify an identification's result on another campaign."""

    model_config = ConfigDict(extra="forbid")
    campaign_id: int
    refit_anchor: bool = False


@router.post(
    "/identifications/{job_id}/verify",
    summary="Predict another campaign's lengths from a result",
    dependencies=[WriteAuth],
)
async def verify_result(state: State, job_id: int, body: VerifyRequest) -> dict[str, Any]:
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
        raise HTTPException(422, f"campaign_id: campaign {body.campaign_id} has no samples")
    try:
        out = await asyncio.to_thread(verify, result["result"], samples,
                                      VerifyOptions(refit_anchor=body.refit_anchor))  # fmt: skip
    except (ValueError, KeyError) as exc:
        raise HTTPException(422, f"campaign {body.campaign_id}: {exc}") from exc
    return out.to_json()


class CheckPosesBody(BaseModel):
    """A robot's check poses [deg]."""

    model_config = ConfigDict(extra="forbid")
    poses_deg: Annotated[
        list[Annotated[list[float], Field(min_length=6, max_length=6)]],
        Field(min_length=3, max_length=100),
    ]


@router.put(
    "/robots/{robot_id}/check-poses", summary="Set the drift-check poses", dependencies=[WriteAuth]
)
def put_check_poses(state: State, robot_id: int, body: CheckPosesBody) -> CheckPoses:
    """3 to 100 joint vectors [deg]; they replace the default (spread poses of the
    calibration's samples)."""
    for i, pose in enumerate(body.poses_deg):
        if not all(math.isfinite(v) for v in pose):
            raise HTTPException(422, f"poses_deg[{i}]: not finite")
    return state.store.set_check_poses(robot_id, body.poses_deg)


@router.get(
    "/robots/{robot_id}/check-poses", summary="The drift-check poses", dependencies=[ReadAuth]
)
def get_check_poses(state: State, robot_id: int) -> CheckPoses:
    """The user's poses (``source`` user) or the default (``source`` default: spread poses
    of the accepted calibration's samples; 404 without one)."""
    return check_poses(state.store, robot_id, state.settings.drift.n_poses)


@router.post(
    "/robots/{robot_id}/checks",
    status_code=status.HTTP_202_ACCEPTED,
    summary="Start a drift check",
    dependencies=[WriteAuth],
)
async def start_check(state: State, robot_id: int) -> CheckRow:
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
    state: State, robot_id: int, limit: int = Query(100, ge=1, le=1000)
) -> list[CheckRow]:
    """The newest ``limit`` checks, oldest first: ``status`` running/ok/drift/failed,
    ``rms_mm``, ``threshold_mm``, ``campaign_id``, ``poses_deg``."""
    state.store.robot(robot_id)
    return state.store.list_checks(robot_id, limit=limit)
