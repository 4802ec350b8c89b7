"""What the store returns: one ``TypedDict`` per kind of row.

They are plain dicts at run time (the routes return them as JSON unchanged), and the REST
API uses them as its response models (:mod:`daemon.api.schemas`), so the keys and their
order here are the REST contract: add keys, never remove or rename one.

Units: joint angles and their standard deviations in degrees (``q1..q6``,
``q1_std..q6_std``), lengths in millimetres, every timestamp (``t_start``, ``t_end``,
``t_wall``, ``created_at``, ``started_at``, ``finished_at``, ``exported_at``) in seconds since
the Unix epoch (UTC). Decoded JSON columns (``model``, ``options``, ``result``, ``detail``)
are strict JSON: a non-finite float was stored as null.

``typing_extensions.TypedDict`` rather than ``typing.TypedDict``: pydantic validates the
latter only on Python >= 3.12.
"""

from __future__ import annotations

from enum import StrEnum
from typing import Any, Final, Literal, NotRequired, get_args

from typing_extensions import TypedDict

from calib.dataset import JOINT_COLUMNS
from calib.monitor.holdcheck import CHECK_VERDICTS, CheckVerdict
from daemon.sampler.capture import CaptureMode


class JobState(StrEnum):
    """The one home of an identification job's states: the store's CHECK constraint, the
    job manager, the REST schema and the page (``GET /options``) read them from here."""

    QUEUED = "queued"
    RUNNING = "running"
    SUCCEEDED = "succeeded"
    FAILED = "failed"
    CANCELLED = "cancelled"

    @property
    def finished(self) -> bool:
        """True for the states after which nothing changes."""
        return self in JOB_FINISHED


#: The job states after which nothing changes.
JOB_FINISHED: frozenset[JobState] = frozenset(
    {JobState.SUCCEEDED, JobState.FAILED, JobState.CANCELLED}
)
JobStatus = JobState

#: The one home of a hold check's states (``running`` until it ends ``ok``, ``not_held`` or
#: ``failed``): the store's CHECK constraint, :mod:`daemon.store.checks` and
#: :mod:`daemon.monitors.holdcheck` read them here. The verdicts ``ok`` and ``not_held`` are calib's
#: (:data:`calib.monitor.holdcheck.CheckVerdict`, the pure decision).
CheckStatus = Literal["running", CheckVerdict, "failed"]
CHECK_STATUSES: Final[tuple[str, ...]] = get_args(CheckStatus)
#: The states of a check that reached a verdict (it has an RMS and a threshold).
CHECK_JUDGED: Final[tuple[str, ...]] = CHECK_VERDICTS
#: What started a hold check: the operator or the schedule.
CheckTrigger = Literal["manual", "schedule"]
CHECK_TRIGGERS: Final[tuple[str, ...]] = get_args(CheckTrigger)


class RobotRow(TypedDict):
    """A physical robot: its own ``name`` (cell, serial number; unique) and its nominal model
    (:meth:`calib.models.RobotModel.to_dict`) called ``model_name``."""

    id: int
    #: The robot's own name, unique among robots.
    name: str
    #: The name of its nominal model (a built-in model's name or the model file's ``name``).
    model_name: str
    convention: Literal["dh", "mdh"]
    model: dict[str, Any]
    source: Literal["builtin", "uploaded"]
    created_at: float
    #: The job id of the robot's current calibration (None: not calibrated yet).
    current_identification_id: int | None


class CampaignRow(TypedDict):
    """A campaign with its robot's name, its sample counts, ``plan_id``: the id of its
    current (newest) pose plan, None while it has none (``GET /campaigns/{id}/plan`` is then a
    404, so a client asks for the plan only when this is set), and ``anchors``: the anchor
    ids of its included samples, sorted (each anchor adds parameters to identify)."""

    id: int
    name: str
    robot_id: int
    notes: str
    auto_capture: bool
    auto_anchor: str
    created_at: float
    robot_name: str
    #: The name of the robot's nominal model.
    robot_model_name: str
    n_samples: int
    n_excluded: int
    n_included: int
    plan_id: int | None
    anchors: list[str]


class JointsDeg(TypedDict):
    """The joint angles of a pose [deg]: the one place the ``q1..q6`` keys of a row are
    written (every row with a pose derives from it; they equal
    :data:`calib.dataset.JOINT_COLUMNS`, checked below)."""

    q1: float
    q2: float
    q3: float
    q4: float
    q5: float
    q6: float


class JointsStdDeg(TypedDict):
    """Standard deviations of the joint angles over a capture window [deg], ``q1_std..q6_std``
    (None for imported rows)."""

    q1_std: float | None
    q2_std: float | None
    q3_std: float | None
    q4_std: float | None
    q5_std: float | None
    q6_std: float | None


if tuple(JointsDeg.__annotations__) != JOINT_COLUMNS or tuple(
    JointsStdDeg.__annotations__
) != tuple(f"{q}_std" for q in JOINT_COLUMNS):  # pragma: no cover - a definition error
    raise ImportError("daemon.store.rows: the joint keys differ from calib.dataset.JOINT_COLUMNS")


# SampleRow's keys, in their REST order, from the bases above (a TypedDict lists the keys of
# its bases first, in order, then its own).
class _SampleIds(TypedDict):
    id: int
    campaign_id: int


class _SampleMean(_SampleIds, JointsDeg):
    length_mm: float
    anchor: str


class _SampleStd(_SampleMean, JointsStdDeg):
    length_std_mm: float | None


class SampleRow(_SampleStd):
    """A sample: the mean pose [deg] and cable length [mm] of a capture, or an imported row
    (imported rows have no std, count, timestamps or mode: None). Keys in order: ``id``,
    ``campaign_id``, ``q1..q6``, ``length_mm``, ``anchor``, ``q1_std..q6_std``,
    ``length_std_mm``, then those below."""

    count: int | None
    t_start: float | None
    t_end: float | None
    mode: CaptureMode | None
    excluded: bool
    excluded_reason: str | None
    source: Literal["capture", "import"]
    created_at: float
    pose_group: str | None


class _ReadingTime(TypedDict):
    t_wall: float


class RawReading(_ReadingTime, JointsDeg):
    """One reading of a capture's settled window: ``t_wall``, ``q1..q6``, ``length_mm``."""

    length_mm: float


class ExportedSample(SampleRow):
    """A sample in :class:`CampaignExport`, with its raw readings when asked for."""

    raw_readings: NotRequired[list[RawReading]]


class CampaignExport(TypedDict):
    """``cablecal db export --format json``: the campaign, its robot and every sample."""

    format: str
    format_version: int
    schema_version: int
    exported_at: float
    campaign: CampaignRow
    robot: RobotRow
    samples: list[ExportedSample]


class JobProgress(TypedDict):
    """How far a job is: ``fraction`` 0–1, and the solver's newest ``iteration`` (whole
    iterations of the whole fit, counted across stages and robust rounds) with its data RMS
    ``cost_rms_mm`` [mm] (None until the solver reports one)."""

    fraction: float
    iteration: int | None
    cost_rms_mm: float | None


class JobRow(TypedDict):
    """An identification job; ``options`` are :class:`calib.identify.IdentifyOptions`'s."""

    id: int
    campaign_id: int
    robot_id: int
    method: str
    options: dict[str, Any]
    status: JobState
    progress: JobProgress
    message: str
    error: str | None
    created_at: float
    started_at: float | None
    finished_at: float | None
    interrupted: bool
    #: True for the job whose result is its robot's current calibration.
    current: bool


class ResultRow(TypedDict):
    """A job's result: ``result`` is the ``result.json`` contract of ``cablecal identify``."""

    id: int
    job_id: int
    campaign_id: int
    robot_id: int
    result: dict[str, Any]
    accepted: bool
    current: bool
    created_at: float


class CalibratedModel(TypedDict):
    """A robot's newest accepted calibration: DH rows ``joint, alpha_deg, a_mm, d_mm,
    theta_deg``, the tool point [mm] and the ``after`` metrics, from its result."""

    robot_id: int
    robot: str
    convention: str
    dh: list[dict[str, Any]] | None
    tool_mm: list[float | None] | None
    method: str | None
    job_id: int
    campaign_id: int
    result_id: int
    created_at: float
    metrics: dict[str, Any] | None


class EventRow(TypedDict):
    """A device or daemon event (``link_down``, ``capture_rejected``, …)."""

    id: int
    t_wall: float
    kind: str
    device: str | None
    campaign_id: int | None
    message: str
    detail: dict[str, Any] | None
