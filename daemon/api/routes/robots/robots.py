"""Robots (each a physical robot with its own name and nominal model) and their calibrated
models."""

from __future__ import annotations

from pathlib import PurePath
from typing import Any, Literal

from fastapi import APIRouter, HTTPException, Query, Response, status
from typing_extensions import NotRequired, TypedDict  # noqa: UP035 (pydantic on 3.11)

from calib.default_robot import DEFAULT_ROBOT_MODEL
from calib.models import (
    BUILTIN_MODELS,
    ModelError,
    RobotModel,
    builtin_model,
    model_from_mapping,
    parse_model_text,
)
from daemon.api.deps import AppState, ReadAuth, RobotId, State, WriteAuth
from daemon.api.errors import error_responses, unprocessable
from daemon.api.http.downloads import download_headers
from daemon.api.schemas import (
    CampaignCreate,
    ModelFileText,
    RobotCreate,
)
from daemon.api.text_rules import not_printable
from daemon.store import CalibratedModel, RobotRow, StoreConflict

router = APIRouter(
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


class BuiltinModelOut(TypedDict):
    """A built-in nominal model the page offers for a new robot."""

    name: str
    #: Whether a campaign without a model gets it (:data:`calib.default_robot.DEFAULT_ROBOT_MODEL`).
    default: bool
    #: The arm's maker in lower case (the library file's ``# maker:``: abb, fanuc, hsr, kuka,
    #: ur), None when the file does not say.
    maker: str | None
    #: The maker's designation of the arm (``# title:``), None when the file does not say.
    title: str | None


def model_maker(model: RobotModel) -> str | None:
    """The maker of a robot's model, lower case: its ``[controller] maker`` (not ``other``),
    else the robot library's ``# maker:`` line of the arm of that name; None when neither
    says."""
    from calib.robots.files import library_info, library_names

    said = model.controller.maker
    if said and said != "other":
        return said
    if model.name in library_names():
        maker = library_info(model.name).maker
        return maker.lower() if maker else None
    return None


def model_of_file(file: ModelFileText, loc: tuple[str, ...]) -> RobotModel:
    """The model of a picked file: TOML or JSON by its extension; a 422 naming the file and
    what is wrong (unknown extension, syntax with its line, a missing field)."""
    suffix = PurePath(file.filename).suffix.lower().lstrip(".")
    if suffix not in ("toml", "json"):
        raise unprocessable(
            (*loc, "filename"),
            f"model file {file.filename!r}: a robot model is a .toml or .json file "
            "(name, convention, tool_mm, joints: see examples/hsr-jr680.toml)",
        )
    try:
        return parse_model_text(file.text, suffix)
    except ModelError as exc:
        raise unprocessable((*loc, "text"), f"model file {file.filename!r}: {exc}") from exc


def _model_of(value: str | dict[str, Any], loc: tuple[str, ...]) -> tuple[RobotModel, bool]:
    """A built-in model by name or a model mapping, and whether it is built in (422 naming
    ``loc`` otherwise)."""
    if isinstance(value, str):
        try:
            return builtin_model(value), True
        except (KeyError, ValueError) as exc:
            raise unprocessable(loc, f"unknown built-in model {value!r} ({exc})") from exc
    try:
        return model_from_mapping(value), False
    except ModelError as exc:
        raise unprocessable(loc, f"{loc[-1]}.{exc}") from exc


def _ensure(
    state: AppState, name: str | None, model: RobotModel, builtin: bool, field: str
) -> RobotRow:
    """The robot called ``name`` (None: the model's name) with ``model``; 409 if that name is
    another model's robot, 422 naming ``field`` (the body's model field) if the model's name
    is not printable."""
    if why := not_printable(model.name):
        raise unprocessable(
            ("body", field, "name"), f"{field}.name: {why}: only printable text is allowed"
        )
    try:
        return state.store.ensure_robot(name, model, "builtin" if builtin else "uploaded")[0]
    except StoreConflict as exc:
        raise HTTPException(409, str(exc)) from exc


def robot_for_campaign(state: AppState, body: CampaignCreate) -> RobotRow:
    """The robot a new campaign is captured on: ``robot_id`` (an existing robot), or the robot
    called ``robot`` (default: the model's name) with ``robot_model`` or
    ``robot_model_file``; the same name and model is the same robot again."""
    given = body.model_fields_set
    if body.robot_id is not None:
        if given & {"robot", "robot_model", "robot_model_file"}:
            raise unprocessable(
                ("body", "robot_id"),
                "robot_id: an existing robot takes no robot, robot_model or robot_model_file",
            )
        return state.store.robot(body.robot_id)
    if body.robot_model_file is not None:
        if "robot_model" in given:
            raise unprocessable(
                ("body", "robot_model_file"), "robot_model_file: give it or robot_model, not both"
            )
        model = model_of_file(body.robot_model_file, ("body", "robot_model_file"))
        return _ensure(state, body.robot, model, False, "robot_model_file")
    model, builtin = _model_of(body.robot_model, ("body", "robot_model"))
    return _ensure(state, body.robot, model, builtin, "robot_model")


@router.get("/robots", summary="Every robot (each a physical robot with its own name)")
def list_robots(state: State) -> list[RobotRow]:
    """By id: each robot's own ``name``, its ``model_name``, its nominal model and its current
    calibration's job id (None: not calibrated yet)."""
    return state.store.list_robots()


@router.get("/robots/models", summary="The built-in nominal models")
def builtin_models() -> list[BuiltinModelOut]:
    """The names of :data:`calib.models.BUILTIN_MODELS`, sorted; ``default`` marks the one a
    campaign without a model gets; ``maker`` and ``title`` from the library file."""
    from calib.robots.files import library_info

    out: list[BuiltinModelOut] = []
    for n in sorted(BUILTIN_MODELS):  # the robot library's arms
        info = library_info(n)
        maker = info.maker.lower() if info.maker else None
        out.append(
            {"name": n, "default": n == DEFAULT_ROBOT_MODEL, "maker": maker, "title": info.title}
        )
    return out


@router.post(
    "/robots",
    status_code=status.HTTP_201_CREATED,
    summary="Add a robot, or find it again by its name",
    dependencies=[WriteAuth],
    responses={
        200: {"model": RobotRow, "description": "The robot of that name and model, found again"},
        **error_responses(400, 409),
    },
)
def create_robot(state: State, body: RobotCreate, response: Response) -> RobotRow:
    """A new robot called ``name`` with a built-in ``model``, a model mapping, or a
    ``model_file`` (TOML or JSON): 201. The same name with the same model is the same robot:
    200 with its record (calibration and hold-check history kept). The name of another model's
    robot: 409."""
    if (body.model is None) == (body.model_file is None):
        raise unprocessable(("body", "model"), "model: give a model or a model_file (one of them)")
    if body.model_file is not None:
        model, builtin = model_of_file(body.model_file, ("body", "model_file")), False
    else:
        assert body.model is not None
        model, builtin = _model_of(body.model, ("body", "model"))
    before = state.store.robot_named(body.name)
    row = _ensure(state, body.name, model, builtin, "model" if body.model else "model_file")
    if before is not None:
        response.status_code = status.HTTP_200_OK
    return row


@router.get("/robots/{robot_id}", summary="One robot and its nominal model")
def get_robot(state: State, robot_id: RobotId) -> RobotRow:
    return state.store.robot(robot_id)


@router.get(
    "/robots/{robot_id}/calibrated-model",
    summary="The latest accepted calibrated DH table, or a model file",
    response_model=CalibratedModel | ModelFile,
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
