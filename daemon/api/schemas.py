"""Request and response bodies of the REST API (pydantic; they document /docs).

Every request body lives here and derives from the one strict body class,
:class:`StrictBody`; the routers import them."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import (
    AliasChoices,
    BaseModel,
    ConfigDict,
    Field,
    StringConstraints,
    TypeAdapter,
    ValidationInfo,
    field_validator,
)
from typing_extensions import TypedDict

from calib.default_robot import DEFAULT_ROBOT_MODEL
from calib.models import BUILTIN_MODELS
from calib.options import (
    DriftMode,
    Holdout,
    IdentifyOptions,
    Method,
    PriorWeight,
    Robust,
    default,
    spec,
)
from calib.planning import PlanOptions
from calib.sample_fields import DEFAULT_ANCHOR
from daemon.api.deps import MAX_ID
from daemon.api.text_rules import (
    MAX_NAME_CHARS,
    MAX_NOTES_CHARS,
    Anchor,
    Name,
    Notes,
    Reason,
    no_surrogates,
)
from daemon.store.rows import CampaignRow, JobRow


class StrictBody(BaseModel):
    """Request bodies: no unknown keys, strict types (``"yes"`` is not a boolean, ``"1"`` not a
    number), finite numbers only (NaN and ±Infinity are a 422 in every float field, nested
    bodies and lists included), every string valid Unicode."""

    model_config = ConfigDict(extra="forbid", strict=True, allow_inf_nan=False)

    @field_validator("*", mode="before")
    @classmethod
    def _unicode(cls, value: Any, info: ValidationInfo) -> Any:
        no_surrogates(value, "text")
        # JSON Schema's "integer" includes 2.0: a whole float is taken for an int field
        # (strict mode refuses it otherwise; 2.5 and "2" stay errors).
        field = cls.model_fields.get(info.field_name or "")
        if (
            isinstance(value, float)
            and value.is_integer()
            and field is not None
            and field.annotation in (int, int | None)
        ):
            return int(value)
        return value


class ModelFileText(StrictBody):
    """A robot model file as the operator picked it: its file name (``.toml`` or ``.json``
    decides the format) and its text."""

    filename: Annotated[str, StringConstraints(min_length=1, max_length=255)]
    text: Annotated[str, StringConstraints(max_length=100_000)]  # a model file: a few kB


class RobotCreate(StrictBody):
    """A physical robot: its own name and its nominal model (exactly one of ``model`` and
    ``model_file``)."""

    name: Name = Field(
        description=f"The robot's own name (cell, serial number), 1..{MAX_NAME_CHARS} "
        "characters; the same name is the same robot again"
    )
    model: (
        Annotated[
            str,
            StringConstraints(max_length=64),
            Field(json_schema_extra={"enum": sorted(BUILTIN_MODELS)}),
        ]
        | dict[str, Any]
        | None
    ) = Field(None, description="A built-in model name, or a model as a mapping")
    model_file: ModelFileText | None = Field(
        None, description="A model file (TOML or JSON, by its extension) as text"
    )


class CampaignCreate(StrictBody):
    """A new calibration campaign."""

    name: Name = Field(description=f"1..{MAX_NAME_CHARS} characters, not blank")
    robot_id: int | None = Field(
        None, ge=1, le=MAX_ID, description="An existing robot (GET /robots); then no model"
    )
    robot: Name | None = Field(
        None,
        description="The robot's own name (cell, serial number): the same name is the same "
        "robot (its calibration and hold-check history go on); a new name makes a robot of the "
        "given model. Without it the robot is named after its model.",
    )
    robot_model_file: ModelFileText | None = Field(
        None, description="The robot's model file (TOML or JSON) as text, instead of robot_model"
    )
    robot_model: (
        Annotated[
            str,
            StringConstraints(max_length=64),
            Field(json_schema_extra={"enum": sorted(BUILTIN_MODELS)}),
        ]
        | dict[str, Any]
    ) = Field(
        DEFAULT_ROBOT_MODEL,
        description=(
            f"A built-in model name ({DEFAULT_ROBOT_MODEL}), or an uploaded model as a mapping: "
            "name, convention (dh|mdh), tool_mm, joints: [{alpha_deg, a_mm, d_mm, theta_deg, "
            "limits_deg}] (the TOML/JSON model file format of `cablecal identify --robot`)."
        ),
    )
    notes: Notes = Field("", description=f"At most {MAX_NOTES_CHARS} characters")


class CaptureRequest(StrictBody):
    """A manual capture."""

    joints_deg: Annotated[list[float], Field(min_length=6, max_length=6)] | None = Field(
        None, description="Joint angles [deg], only with the manual robot driver."
    )
    anchor: Anchor = Field(DEFAULT_ANCHOR, description="Sensor position id (not blank).")
    repeat: bool = Field(
        False,
        description="Store it even at a pose the campaign has captured already (the operator "
        "confirmed the repeat); without it such a capture is refused (409 not_new_pose), the "
        "rule auto capture follows.",
    )


class AutoCapture(StrictBody):
    """Switch auto capture on or off."""

    enabled: bool = Field(description="JSON true or false (no strings, no numbers)")
    anchor: Anchor = Field(DEFAULT_ANCHOR, description="Sensor position id (not blank).")


class SamplePatch(StrictBody):
    """Exclude a sample from identification, or include it again."""

    excluded: bool
    reason: Reason | None = None


def _option(name: str) -> Any:
    """The body field of identification option ``name``: default, bounds and description
    from :mod:`calib.options` (the literal types are imported from there too)."""
    sp = spec(name)
    return Field(default(name), description=sp.help, gt=sp.gt, ge=sp.ge, lt=sp.lt, le=sp.le)


_ParamName = Annotated[str, StringConstraints(max_length=64)]


# The fields of IdentificationRequest are the one list of the identification options a user
# sets: the API's body, the page's form (through GET /options/identify) and `cablecal
# identify`'s options (tests/test_options.py holds the CLI to it).
class IdentificationRequest(StrictBody):
    """Options of an identification job (see ``cablecal identify --help``); a subset of
    :class:`calib.options.IdentifyOptions` under the same names (``fixed`` is still read as
    the old spelling of ``fix``). ``GET /options/identify`` serves each field's spec."""

    method: Method = _option("method")
    test_fraction: float = _option("test_fraction")
    seed: int = _option("seed")
    holdout: Holdout = _option("holdout")
    robust: Robust = _option("robust")
    fix: Annotated[list[_ParamName], Field(max_length=200)] = Field(
        default_factory=list,
        description=spec("fix").help,
        validation_alias=AliasChoices("fix", "fixed"),
    )
    free: Annotated[list[_ParamName], Field(max_length=200)] = Field(
        default_factory=list, description=spec("free").help
    )
    prior: bool = _option("prior")
    prior_mm: float = _option("prior_mm")
    prior_deg: float = _option("prior_deg")
    prior_weight: PriorWeight = _option("prior_weight")
    drift: DriftMode = _option("drift")
    noise_mm: Annotated[float, Field(gt=spec("noise_mm").gt)] | None = Field(
        None, description=f"{spec('noise_mm').help}; default from the config."
    )
    noise_rank: bool = _option("noise_rank")

    def to_options(self, noise_mm: float | None = None) -> IdentifyOptions:
        """The request's :class:`calib.options.IdentifyOptions`, made once here and passed on
        (the job's check and its worker take this object); ``noise_mm``: the ``[jobs]``
        default when the body has none (None: the option's own default)."""
        out = self.model_dump(exclude={"fix", "free", "noise_mm"})
        out["fix"] = tuple(self.fix)
        out["free"] = tuple(self.free)
        noise = self.noise_mm if self.noise_mm is not None else noise_mm
        if noise is not None:
            out["noise_mm"] = noise
        return IdentifyOptions(**out)


# ------------------------------------------------------------------ compensation targets
#: Most targets one compensation request may carry (the body is bounded by the request
#: guard: :data:`daemon.api.http.guard.MAX_COMPENSATE_BYTES`).
MAX_TARGETS = 10_000

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


def target_list(model: type[StrictBody]) -> Any:
    return Annotated[list[model], Field(min_length=1, max_length=MAX_TARGETS)]  # type: ignore[valid-type]


TARGET_MODELS: tuple[type[StrictBody], ...] = (JointTarget, PoseTarget, PositionTarget)
TARGET_LISTS = {m: TypeAdapter(target_list(m)) for m in TARGET_MODELS}
ANY_TARGETS: TypeAdapter[Any] = TypeAdapter(
    Annotated[list[dict[str, Any]], Field(min_length=1, max_length=MAX_TARGETS)]
)


def inline_defs(schema: dict[str, Any]) -> dict[str, Any]:
    """A JSON schema with its local ``#/$defs/...`` references replaced by their definitions
    and no ``$defs`` left: a schema embedded in the OpenAPI document by hand (an
    ``openapi_extra`` request body) must not point at a ``$defs`` the document lacks."""
    defs = schema.get("$defs", {})

    def resolve(node: Any) -> Any:
        if isinstance(node, dict):
            ref = node.get("$ref")
            if isinstance(ref, str) and ref.startswith("#/$defs/"):
                return resolve(defs[ref.removeprefix("#/$defs/")])
            return {k: resolve(v) for k, v in node.items() if k != "$defs"}
        if isinstance(node, list):
            return [resolve(v) for v in node]
        return node

    resolved: dict[str, Any] = resolve(schema)
    return resolved


#: The JSON request body as documented: one of the three target lists (self-contained).
TARGETS_SCHEMA = {
    "anyOf": [inline_defs(TypeAdapter(target_list(m)).json_schema()) for m in TARGET_MODELS]
}


# ------------------------------------------------------------------ verification
class VerifyRequest(StrictBody):
    """Verify an identification's result on another campaign."""

    campaign_id: int = Field(ge=1, le=MAX_ID, description="The campaign whose samples to predict")
    refit_anchor: bool = Field(False, description="Fit the anchor and zero offset first")


# ------------------------------------------------------------------ hold-check poses
class CheckPosesBody(StrictBody):
    """A robot's check poses [deg]."""

    poses_deg: Annotated[
        list[Annotated[list[JointDeg], Field(min_length=6, max_length=6)]],
        Field(min_length=3, max_length=100),
    ]


# ------------------------------------------------------------------ pose plans
# The defaults come from :class:`calib.planning.PlanOptions` (one definition).
_D = PlanOptions()

#: Bounds of a plan request: what one request may ask of the 2-core cell PC.
MAX_POSES = 200
MAX_CANDIDATES = 10_000
MAX_ANCHORS = 4

Coordinate = Annotated[float, Field(ge=-10_000.0, le=10_000.0, allow_inf_nan=False)]
Extension = Annotated[float, Field(ge=0, le=10_000, allow_inf_nan=False)]


class PlanRequest(StrictBody):
    """Options of a plan (see ``cablecal plan --help``; units in the names). The robot is the
    campaign's. Strict: no unknown keys, ``"1"`` is not a number, ``"yes"`` not a boolean;
    pairs and triples are JSON lists of that length."""

    # The schema states the one rule between fields: anchors_mm, unless start_from_samples.
    model_config = ConfigDict(
        json_schema_extra={
            "anyOf": [
                {"required": ["anchors_mm"], "properties": {"anchors_mm": {"type": "array"}}},
                {
                    "required": ["start_from_samples"],
                    "properties": {"start_from_samples": {"const": True}},
                },
            ]
        }
    )

    anchors_mm: (
        Annotated[
            list[Annotated[list[Coordinate], Field(min_length=3, max_length=3)]],
            Field(min_length=1, max_length=MAX_ANCHORS),
        ]
        | None
    ) = Field(
        None,
        description="Anchor guesses [x, y, z] [mm] in the robot base frame, one per sensor "
        "position; default (with start_from_samples): where the campaign's samples put them.",
    )
    anchor_ids: Annotated[list[Anchor], Field(min_length=1, max_length=MAX_ANCHORS)] | None = Field(
        None,
        description="Id per anchor (default A, B, …); an id of the samples means the "
        "sensor has not moved.",
    )
    n: int = Field(_D.n, ge=1, le=MAX_POSES, description="Poses to plan, all anchors.")
    candidates: int = Field(
        _D.candidates, ge=1, le=MAX_CANDIDATES, description="Random feasible candidate poses."
    )
    seed: int = Field(_D.seed, ge=0, le=2**32 - 1)
    min_z_mm: float = Field(
        _D.min_z_mm,
        ge=-10_000,
        le=10_000,
        allow_inf_nan=False,
        description="Flange and tool point above this z.",
    )
    extension_mm: Annotated[list[Extension], Field(min_length=2, max_length=2)] = Field(
        list(_D.extension_mm), description="Allowed cable extension [min, max] [mm]."
    )
    anchor_uncertainty_mm: float = Field(
        _D.anchor_uncertainty_mm,
        ge=0,
        le=1000,
        allow_inf_nan=False,
        description="How far the guess may be off.",
    )
    noise_mm: float | None = Field(
        None,
        gt=0,
        le=10,
        allow_inf_nan=False,
        description="1σ noise of one captured length [mm]; default (null): from the cell "
        "(the robot's accepted result, the campaign's captures, the live indicator, else "
        f"{_D.noise_mm}); the summary names it (noise_source).",
    )
    joint_speed_deg_s: Annotated[
        list[Annotated[float, Field(gt=0, le=1000, allow_inf_nan=False)]],
        Field(min_length=6, max_length=6),
    ] = Field(list(_D.joint_speed_deg_s), description="Joint speeds for the moves [deg/s].")
    dwell_s: float = Field(
        _D.dwell_s,
        ge=0,
        le=600,
        allow_inf_nan=False,
        description="Settle and read time per pose.",
    )
    start_from_samples: bool = Field(
        False, description="Plan more poses on top of the campaign's included samples."
    )

    def options(self, noise_mm: float | None = None) -> PlanOptions:
        """The engine's options (anchor ids set by the caller when taken from samples), with
        ``noise_mm`` when the request gives none (else the engine's default)."""
        noise = self.noise_mm if self.noise_mm is not None else noise_mm
        return PlanOptions(
            n=self.n,
            candidates=self.candidates,
            seed=self.seed,
            min_z_mm=self.min_z_mm,
            extension_mm=(self.extension_mm[0], self.extension_mm[1]),
            anchor_uncertainty_mm=self.anchor_uncertainty_mm,
            noise_mm=_D.noise_mm if noise is None else noise,
            joint_speed_deg_s=tuple(self.joint_speed_deg_s),
            dwell_s=self.dwell_s,
            anchor_ids=None if self.anchor_ids is None else tuple(self.anchor_ids),
        )


# ===================================================================== response models
# What the routes return: the REST contract. A resource is the store's typed row as it is
# (daemon.store.rows: one definition for the store, the routes and /docs); pydantic validates
# it on the way out. Keys may be added, never removed or renamed.


class CampaignOut(CampaignRow):
    """A campaign with what identify needs of it at the default options
    (:mod:`calib.min_samples`): ``min_samples_to_identify``, the fewest included samples
    ``POST /campaigns/{id}/identifications`` accepts (default ``test_fraction`` 0.2), and
    ``min_training_samples``, the fewest training rows (for another test fraction: the
    smallest ``n`` with ``n - held_out(n, test_fraction)`` at least that). Both follow the robot
    model and the number of ``anchors`` (each further anchor adds 4 parameters).
    ``recommended_samples`` (``recommended_training_samples`` training rows) is the count at
    which the default ``robust auto`` can also screen outliers
    (:func:`calib.options.training_rows_recommended`)."""

    min_training_samples: int
    min_samples_to_identify: int
    recommended_training_samples: int
    recommended_samples: int


class JobView(JobRow):
    """A job with its result: ``result`` is the ``result.json`` contract of ``cablecal
    identify`` once succeeded (else null); ``accepted`` whether it is the robot's calibrated
    model."""

    result: dict[str, Any] | None
    accepted: bool


class ImportResult(TypedDict):
    """A CSV import: how many samples, and their ids in file order."""

    imported: int
    sample_ids: list[int]


class Health(TypedDict):
    """Liveness."""

    status: Literal["ok"]
    version: str
    uptime_s: float


class ServiceStatus(TypedDict):
    """Devices, sampler and jobs (see ``GET /status``)."""

    devices: dict[str, Any]
    sampler: dict[str, Any] | None
    jobs: dict[str, Any]
    hold_check: dict[str, Any] | None
    watch: dict[str, Any] | None
    uptime_s: float
