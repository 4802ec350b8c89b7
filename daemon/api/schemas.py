"""Request and response bodies of the REST API (pydantic; they document /docs)."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field
from typing_extensions import TypedDict

from calib.options import Holdout, Method, PriorWeight, Robust, default, spec
from daemon.store.rows import CalibratedModel, CampaignRow, EventRow, JobRow, RobotRow, SampleRow


class _Body(BaseModel):
    model_config = ConfigDict(extra="forbid")


class CampaignCreate(_Body):
    """A new calibration campaign."""

    name: Annotated[str, Field(min_length=1, max_length=200)]
    robot_model: str | dict[str, Any] = Field(
        "hsr-jr680",
        description=(
            "A built-in model name (hsr-jr680), or an uploaded model as a mapping: "
            "name, convention (dh|mdh), tool_mm, joints: [{alpha_deg, a_mm, d_mm, theta_deg, "
            "limits_deg}] (the TOML/JSON model file format of `cablecal identify --robot`)."
        ),
    )
    notes: str = ""


class CaptureRequest(_Body):
    """A manual capture."""

    joints_deg: Annotated[list[float], Field(min_length=6, max_length=6)] | None = Field(
        None, description="Joint angles [deg], only with the manual robot driver."
    )
    anchor: Annotated[str, Field(min_length=1, max_length=32)] = Field(
        "A", description="Sensor position id."
    )


class AutoCapture(_Body):
    """Switch auto capture on or off."""

    enabled: bool
    anchor: Annotated[str, Field(min_length=1, max_length=32)] = "A"


class SamplePatch(_Body):
    """Exclude a sample from identification, or include it again."""

    excluded: bool
    reason: str | None = Field(None, max_length=500)


def _option(name: str) -> Any:
    """The body field of identification option ``name``: default, bounds and description
    from :mod:`calib.options` (the literal types are imported from there too)."""
    sp = spec(name)
    return Field(default(name), description=sp.help, gt=sp.gt, ge=sp.ge, lt=sp.lt)


class IdentificationRequest(_Body):
    """Options of an identification job (see ``cablecal identify --help``); a subset of
    :class:`calib.options.IdentifyOptions`, with ``fix`` spelled ``fixed``."""

    method: Method = _option("method")
    test_fraction: float = _option("test_fraction")
    seed: int = _option("seed")
    holdout: Holdout = _option("holdout")
    robust: Robust = _option("robust")
    fixed: list[str] = Field(default_factory=list, description=spec("fix").help)
    free: list[str] = Field(default_factory=list, description=spec("free").help)
    prior: bool = _option("prior")
    prior_mm: float = _option("prior_mm")
    prior_deg: float = _option("prior_deg")
    prior_weight: PriorWeight = _option("prior_weight")
    noise_mm: Annotated[float, Field(gt=spec("noise_mm").gt)] | None = Field(
        None, description=f"{spec('noise_mm').help}; default from the config."
    )

    def to_options(self) -> dict[str, Any]:
        """Keyword arguments of :class:`calib.options.IdentifyOptions`."""
        out = self.model_dump(exclude={"fixed", "free", "noise_mm"})
        out["fix"] = tuple(self.fixed)
        out["free"] = tuple(self.free)
        if self.noise_mm is not None:
            out["noise_mm"] = self.noise_mm
        return out


# ===================================================================== response models
# What the routes return: the REST contract. A resource is the store's typed row as it is
# (daemon.store.rows: one definition for the store, the routes and /docs); pydantic validates
# it on the way out. Keys may be added, never removed or renamed.

CampaignOut = CampaignRow
SampleOut = SampleRow
RobotOut = RobotRow
CalibratedModelOut = CalibratedModel
EventOut = EventRow
JobOut = JobRow


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
    uptime_s: float
