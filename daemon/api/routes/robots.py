"""Robots and their calibrated models."""

from __future__ import annotations

from typing import Any, Literal

from fastapi import APIRouter, HTTPException, Query, Response
from typing_extensions import NotRequired, TypedDict  # noqa: UP035 (pydantic on 3.11)

from daemon.api.deps import ReadAuth, RobotId, State
from daemon.api.downloads import download_headers
from daemon.api.errors import error_responses
from daemon.api.schemas import CalibratedModelOut, RobotOut

router = APIRouter(
    prefix="/robots",
    tags=["robots"],
    dependencies=[ReadAuth],
    responses=error_responses(401, 404, 413, 422),
)


class ModelFileJoint(TypedDict):
    """One joint of a model file: DH row [deg, mm] and its limits [deg]."""

    alpha_deg: float
    a_mm: float
    d_mm: float
    theta_deg: float
    limits_deg: NotRequired[list[float]]


class ModelFile(TypedDict):
    """A robot model file as ``--robot FILE.json`` reads it (:meth:`calib.models.RobotModel
    .to_dict`): what ``GET /robots/{id}/calibrated-model?format=json`` answers."""

    name: str
    convention: Literal["dh", "mdh"]
    tool_mm: list[float]
    joints: list[ModelFileJoint]


#: Media type of each model-file format of ``GET /robots/{id}/calibrated-model?format=``.
EXPORT_MEDIA_TYPES = {
    "toml": "application/toml",
    "urdf": "application/xml",
    "json": "application/json",
}


@router.get("/{robot_id}", summary="One robot and its nominal model")
def get_robot(state: State, robot_id: RobotId) -> RobotOut:
    return state.store.robot(robot_id)


@router.get(
    "/{robot_id}/calibrated-model",
    summary="The latest accepted calibrated DH table, or a model file",
    response_model=CalibratedModelOut | ModelFile,
    responses={
        200: {
            "description": "Without ``format``: the calibrated DH table (CalibratedModel). "
            "With ``format=json``: the model file (ModelFile); ``toml``: the TOML model file; "
            "``urdf``: the URDF (XML).",
            "content": {
                EXPORT_MEDIA_TYPES["toml"]: {"schema": {"type": "string"}},
                EXPORT_MEDIA_TYPES["urdf"]: {"schema": {"type": "string"}},
            },
        },
        **error_responses(409),
    },
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
        return export_response(state, robot_id, format)
    return state.store.calibrated_model(robot_id)


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
