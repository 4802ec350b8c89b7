"""Identification options, defined once: the REST body and the CLI options are built from them.

:class:`IdentifyOptions` is a frozen dataclass whose fields carry their help text, choices and
bounds as field metadata (:class:`OptionSpec`). :func:`calib.identify.identify`, the job
submission of the daemon, ``cablecal identify`` and the REST request body all read them from
here; :func:`validate` is the one check of options against a sample set.

This module imports only the standard library at import time (the CLI's ``--help`` path reads
it); :func:`validate` imports numpy-based modules when called.
"""

from __future__ import annotations

from collections.abc import Collection, Mapping
from dataclasses import MISSING, dataclass, field, fields, replace
from typing import TYPE_CHECKING, Any, Literal, TypeVar, get_args

if TYPE_CHECKING:
    from calib.dataset import SampleSet
    from calib.models import RobotModel

Method = Literal["ukf-vslm", "lm", "vslm", "ukf", "ekf", "de", "geolm"]
Robust = Literal["auto", "none", "huber", "soft_l1", "reject"]
Holdout = Literal["random", "grouped"]
PriorWeight = Literal["estimated", "fixed", "cv"]
DriftMode = Literal["auto", "none", "steps", "smooth"]

METHODS: tuple[str, ...] = get_args(Method)
ROBUST_MODES: tuple[str, ...] = get_args(Robust)
HOLDOUTS: tuple[str, ...] = get_args(Holdout)
PRIOR_WEIGHTS: tuple[str, ...] = get_args(PriorWeight)
DRIFT_MODES: tuple[str, ...] = get_args(DriftMode)

_G = TypeVar(
    "_G", "SplitOptions", "RobustOptions", "PriorOptions", "DriftOptions", "SolverSettings"
)

#: Training and test rows per draw in the paper's protocol (:mod:`calib.protocol`).
PAPER_N_TRAIN = 100
PAPER_N_TEST = 20

#: Fewest training rows an identification accepts, whatever is fixed: a floor below the real
#: rule of :func:`validate`, which needs more training rows than the parameters identify will
#: solve (on the built-in model with one anchor and the tool point solved: 24 parameters, so
#: 25 rows; each further anchor adds 4).
MIN_TRAINING_SAMPLES = 24

#: Least redundancy (training rows less the fit's effective parameters, prior included) at
#: which ``robust auto`` screens for outliers (:mod:`calib.robust`): with fewer, the residuals'
#: scale rests on too few degrees of freedom to tell an outlier from a good sample (the
#: family-wise Student-t threshold at 30–100 rows is more than 1.5 times the known-σ one).
#: The recommended count (:func:`training_rows_recommended`) adds it to the parameters.
SCREEN_MIN_DOF = 10

#: The 1σ length noise identify assumes when told to assume one [mm] (``prior_weight fixed``,
#: ``noise_rank``; the default weight ``estimated`` takes the noise from the fit's own
#: residuals instead). A chosen round figure, not a measurement, at or just above the noise
#: the estimated weight finds on the bundled real data (bench/prior_weight.md). It is above
#: the planner's :data:`calib.planning.options.PLAN_NOISE_MM`, the noise of one capture,
#: because a fit's residuals also hold what the kinematic model does not explain.
IDENTIFY_NOISE_MM = 0.1

#: Largest seed: numpy's legacy seeding (and so scipy's DE) takes 0..2**32-1.
MAX_SEED = 2**32 - 1


class OptionError(ValueError):
    """An identification option is invalid; ``field`` names it."""

    def __init__(self, field_name: str, message: str) -> None:
        super().__init__(f"{field_name}: {message}")
        self.field = field_name
        self.reason = message


@dataclass(frozen=True)
class OptionSpec:
    """What a field of :class:`IdentifyOptions` accepts, and its help text."""

    help: str
    choices: tuple[str, ...] | None = None
    gt: float | None = None
    ge: float | None = None
    lt: float | None = None
    le: float | None = None

    def check(self, name: str, value: Any) -> None:
        """Raise :class:`OptionError` naming ``name`` when ``value`` is outside the spec."""
        if self.choices is not None and value not in self.choices:
            raise OptionError(name, f"must be one of {', '.join(self.choices)}; got {value!r}")
        if value is None or isinstance(value, bool) or not isinstance(value, int | float):
            return
        if self.gt is not None and not value > self.gt:
            raise OptionError(name, f"must be > {self.gt}; got {value}")
        if self.ge is not None and not value >= self.ge:
            raise OptionError(name, f"must be >= {self.ge}; got {value}")
        if self.lt is not None and not value < self.lt:
            raise OptionError(name, f"must be < {self.lt}; got {value}")
        if self.le is not None and not value <= self.le:
            raise OptionError(name, f"must be <= {self.le}; got {value}")


def _spec(help: str, **spec: Any) -> dict[str, OptionSpec]:
    return {"spec": OptionSpec(help, **spec)}


@dataclass(frozen=True)
class IdentifyOptions:
    """Options of :func:`calib.identify.identify`; each field's help is in its metadata.

    ``ukf_batch_size`` None means 1 for ``ukf`` and ``ekf`` (per-sample updates), and for the
    UKF stage of ``ukf-vslm`` batches growing 1, 2, 4, … to 32 in each epoch (see
    :mod:`calib.solvers.ukf_vslm`). ``holdout="grouped"`` holds out whole pose groups (a
    ``group`` column, or ``n_groups`` Ward clusters of the joint angles) instead of random
    rows: accuracy at poses unlike the training poses.
    """

    method: Method = field(
        default="geolm", metadata=_spec("Identification method", choices=METHODS)
    )
    test_fraction: float = field(
        default=0.2, metadata=_spec("Held-out share, 0 trains on all", ge=0.0, lt=1.0)
    )
    seed: int = field(
        default=0, metadata=_spec("Seed of the split (and of DE), 0..2**32-1", ge=0, le=MAX_SEED)
    )
    holdout: Holdout = field(
        default="random",
        metadata=_spec("Hold out random rows or whole pose groups", choices=HOLDOUTS),
    )
    n_groups: int = field(
        default=10,
        metadata=_spec("Pose clusters for a grouped hold-out without a group column", gt=0),
    )
    robust: Robust = field(
        default="auto",
        metadata=_spec(
            "Robust fit mode; auto: plain fit, and only if it finds gross outliers "
            "(beyond a threshold growing with n), reject them and refit",
            choices=ROBUST_MODES,
        ),
    )
    robust_k: float = field(
        default=1.345, metadata=_spec("Huber / soft-L1 threshold [robust sigma]", gt=0)
    )
    flag_threshold: float = field(
        default=3.5,
        metadata=_spec("Flag (reject) residuals beyond this [robust sigma]; auto: at least", gt=0),
    )
    prior: bool = field(default=True, metadata=_spec("MAP prior toward the nominal model"))
    prior_mm: float = field(default=2.0, metadata=_spec("Prior 1σ of DH lengths [mm]", gt=0))
    prior_deg: float = field(default=0.2, metadata=_spec("Prior 1σ of DH angles [deg]", gt=0))
    prior_tool_mm: float | None = field(
        default=None, metadata=_spec("Prior 1σ of the tool point [mm]", gt=0)
    )
    prior_weight: PriorWeight = field(
        default="estimated",
        metadata=_spec(
            "How the prior is weighed against the data: estimated (noise from the MAP fit's "
            "own residuals), fixed (noise_mm), cv (prior scale by grouped-fold "
            "cross-validation)",
            choices=PRIOR_WEIGHTS,
        ),
    )
    noise_mm: float = field(
        default=IDENTIFY_NOISE_MM,
        metadata=_spec("Assumed 1-sigma length noise (prior_weight fixed, noise_rank) [mm]", gt=0),
    )
    fix: tuple[str, ...] = field(
        default=(), metadata=_spec("Parameter names held at their start (nominal) value")
    )
    free: tuple[str, ...] = field(
        default=(), metadata=_spec("Parameter names solved even if unidentifiable")
    )
    identify_tool: bool = field(default=True, metadata=_spec("Solve for the tool point"))
    tool_mm: tuple[float, float, float] | None = field(
        default=None, metadata=_spec("Nominal tool point override [mm]")
    )
    rtol: float = field(default=1e-8, metadata=_spec("Identifiability threshold", gt=0))
    noise_rank: bool = field(
        default=False,
        metadata=_spec(
            "Also fix DH parameters whose predicted 1σ at noise_mm exceeds a plausible error "
            "(prior_mm / prior_deg): near-redundant ones such as d5/theta5 vs the tool point. "
            "Off by default: the default prior holds them softly (the comparison: "
            "bench/design_figures.md)"
        ),
    )
    filter_sigma_mm: float = field(
        default=5.0, metadata=_spec("Filters' initial 1σ of lengths [mm]", gt=0)
    )
    filter_sigma_deg: float = field(
        default=0.5, metadata=_spec("Filters' initial 1σ of angles [deg]", gt=0)
    )
    ukf_epochs: int = field(
        default=2, metadata=_spec("Sweeps of the UKF and EKF over the samples (T3)", gt=0)
    )
    ukf_batch_size: int | None = field(
        default=None, metadata=_spec("Samples per filter update", gt=0)
    )
    vslm_delta0: float = field(default=0.8, metadata=_spec("VSLM initial step size", gt=0))
    vslm_mu: float = field(default=0.95, metadata=_spec("VSLM step-size decay", gt=0, lt=1))
    de_max_generations: int = field(default=300, metadata=_spec("DE generations", gt=0))
    drift: DriftMode = field(
        default="auto",
        metadata=_spec(
            "Model how the measurement changes over the campaign (calib.drift): auto (BIC "
            "chooses none, steps, a smooth drift or both), none, steps (re-zero or sensor "
            "moved), smooth (offset drift over time); geolm, lm and vslm only",
            choices=DRIFT_MODES,
        ),
    )

    def __post_init__(self) -> None:
        for f in fields(self):
            spec(f.name).check(f.name, getattr(self, f.name))


_FIELDS = {f.name: f for f in fields(IdentifyOptions)}


# ------------------------------------------------------------------ the options by concern
# Each step of identify reads only its group: the split (calib.split), the robust fit
# (calib.robust), the prior (calib.prior), the drift model (calib.drift) and the method's
# solver (calib.methods). A group's fields are the flat options of the same name (the JSON,
# REST and CLI names, with their help and bounds above): IdentifyOptions.part builds one.


@dataclass(frozen=True)
class SplitOptions:
    """How identify holds rows out to test (:func:`calib.split.split_rows`)."""

    test_fraction: float
    seed: int
    holdout: Holdout
    n_groups: int


@dataclass(frozen=True)
class RobustOptions:
    """The robust fit (:func:`calib.robust.solve`)."""

    robust: Robust
    robust_k: float
    flag_threshold: float


@dataclass(frozen=True)
class PriorOptions:
    """The MAP prior toward the nominal model and its weight (:mod:`calib.prior`)."""

    prior: bool
    prior_mm: float
    prior_deg: float
    prior_tool_mm: float | None
    prior_weight: PriorWeight
    noise_mm: float


@dataclass(frozen=True)
class DriftOptions:
    """The model of the measurement's drift over the campaign (:mod:`calib.drift`)."""

    drift: DriftMode
    method: Method


@dataclass(frozen=True)
class SolverSettings:
    """The method and its solver's settings (:func:`calib.methods.run`)."""

    method: Method
    seed: int
    filter_sigma_mm: float
    filter_sigma_deg: float
    ukf_epochs: int
    ukf_batch_size: int | None
    vslm_delta0: float
    vslm_mu: float
    de_max_generations: int


OptionGroup = SplitOptions | RobustOptions | PriorOptions | DriftOptions | SolverSettings
GROUPS: tuple[type[OptionGroup], ...] = (
    SplitOptions,
    RobustOptions,
    PriorOptions,
    DriftOptions,
    SolverSettings,
)
for _group in GROUPS:
    assert {f.name for f in fields(_group)} <= set(_FIELDS), _group


def part(options: IdentifyOptions, group: type[_G]) -> _G:
    """The ``group`` (one of :data:`GROUPS`) of ``options``: its fields' values."""
    return group(**{f.name: getattr(options, f.name) for f in fields(group)})


def with_part(options: IdentifyOptions, values: OptionGroup) -> IdentifyOptions:
    """``options`` with the fields of the group ``values`` replaced by its values."""
    return replace(options, **{f.name: getattr(values, f.name) for f in fields(values)})


def spec(name: str) -> OptionSpec:
    """The :class:`OptionSpec` of option ``name``."""
    out: OptionSpec = _FIELDS[name].metadata["spec"]
    return out


def default(name: str) -> Any:
    """The default value of option ``name``."""
    value = _FIELDS[name].default
    assert value is not MISSING
    return value


def options_from_mapping(values: Mapping[str, Any]) -> IdentifyOptions:
    """Options from a mapping (JSON, CLI): lists become tuples; unknown keys name themselves."""
    unknown = [k for k in values if k not in _FIELDS]
    if unknown:
        raise OptionError(unknown[0], f"unknown option; known: {', '.join(_FIELDS)}")
    kwargs: dict[str, Any] = {
        k: tuple(v) if isinstance(v, list | tuple) and k in ("fix", "free", "tool_mm") else v
        for k, v in values.items()
    }
    return IdentifyOptions(**kwargs)


def options_mapping(options: IdentifyOptions) -> dict[str, Any]:
    """Every option by its JSON, REST and CLI name (tuples as lists): the reverse of
    :func:`options_from_mapping`, e.g. a job's stored options."""
    out: dict[str, Any] = {}
    for f in fields(options):
        value = getattr(options, f.name)
        out[f.name] = list(value) if isinstance(value, tuple) else value
    return out


def validate(
    samples: SampleSet,
    options: IdentifyOptions,
    train_rows: Collection[Any] | None = None,
    *,
    model: RobotModel,
) -> None:
    """Check options against a sample set and the robot, before any computation.

    Checks the ``fix``/``free`` names against the parameter layout of the samples' anchors,
    and that the training rows (``train_rows``, the split identify makes:
    :func:`calib.split.split_rows` at the options' test fraction, seed and hold-out; or only
    their count, what ``test_fraction`` leaves) are more than the
    parameters identify will solve (:func:`calib.identifiability.max_solved`: the base set of
    this robot and these anchors at well-spread poses, less ``fix``, plus ``free``), at least
    :data:`MIN_TRAINING_SAMPLES`, and, given ``train_rows``, at least
    :data:`calib.cable.MIN_ANCHOR_SAMPLES` for each anchor (:func:`check_anchor_rows`). Costs
    one Jacobian at 200 poses (milliseconds) the first time for a model, anchors and options
    (the answer is kept).

    Raises
    ------
    OptionError
        ``fix`` or ``free`` names an unknown parameter (the message names the field).
    calib.dataset.SampleError
        Too few training samples (the message names how many are needed and why).
    """
    from calib.cable import ParamLayout
    from calib.sample_fields import DEFAULT_ANCHOR

    # Each field's choices and bounds were checked when the options were made
    # (IdentifyOptions.__post_init__, also on dataclasses.replace): not again here.
    anchors = samples.anchor_ids or (DEFAULT_ANCHOR,)
    known = ParamLayout(anchors).names
    for key in ("fix", "free"):
        bad = [n for n in getattr(options, key) if n not in known]
        if bad:
            raise OptionError(key, f"unknown parameter name(s) {bad}; known: {known}")
    n = len(samples)
    n_train = len(train_rows) if train_rows is not None else n - held_out(n, options.test_fraction)
    check_training_rows(n_train, n, parameters_to_solve(model, anchors, options))
    if train_rows is not None:
        check_anchor_rows(samples, train_rows)


def check_anchor_rows(samples: SampleSet, train_rows: Collection[Any]) -> None:
    """The one rule on each anchor's training rows: at least
    :data:`calib.cable.MIN_ANCHOR_SAMPLES`, the fewest that locate its ``P0`` and zero offset.

    Raises
    ------
    calib.dataset.SampleError
        Naming the anchor, its training rows and its included samples.
    """
    from calib.cable import MIN_ANCHOR_SAMPLES
    from calib.dataset import SampleError

    anchors = samples.anchor_ids
    if len(samples) == 0 or not anchors:
        return
    index = samples.anchor_index()
    counts = [0] * len(anchors)
    for row in train_rows:
        counts[int(index[int(row)])] += 1
    for aid, n_train in zip(anchors, counts, strict=True):
        if n_train < MIN_ANCHOR_SAMPLES:
            n_all = sum(a == aid for a in samples.anchor)
            raise SampleError(
                f"anchor {aid!r} has {n_train} training samples (of {n_all} included); at "
                f"least {MIN_ANCHOR_SAMPLES} are needed to locate it (capture more at this "
                "anchor, or exclude its samples)",
                column="anchor",
            )


def parameters_to_solve(
    model: RobotModel, anchor_ids: tuple[str, ...], options: IdentifyOptions
) -> int:
    """The most parameters identify solves for ``model`` with these anchors and options
    (:func:`calib.identifiability.max_solved`: the base set at well-spread poses, less ``fix``,
    plus ``free``). Costs one Jacobian at 200 poses, once (the answer is kept). ``fix``/``free``
    must name parameters of the anchors' layout (:func:`validate` checks that first)."""
    from calib.cable import ParamLayout
    from calib.identifiability import candidate_mask, max_solved, with_tool

    layout = ParamLayout(anchor_ids)
    candidates = candidate_mask(layout, options.identify_tool, options.fix)
    return max_solved(
        with_tool(model, options.tool_mm), layout, candidates, options.free, rtol=options.rtol
    )


def held_out(n: int, test_fraction: float) -> int:
    """Rows of ``n`` held out to test: ``round(test_fraction * n)`` (Python's rounding, half to
    even). The one count of the hold-out: :func:`validate`, :func:`samples_for_training_rows`,
    :func:`calib.split.split_rows` and the daemon's readiness route use it."""
    return round(test_fraction * n)


def training_rows_needed(n_params: int) -> int:
    """The fewest training rows :func:`check_training_rows` accepts for ``n_params`` solved
    parameters: one more than the parameters, and at least :data:`MIN_TRAINING_SAMPLES`."""
    return max(n_params + 1, MIN_TRAINING_SAMPLES)


def training_rows_recommended(n_params: int) -> int:
    """The training rows at which ``robust auto`` can screen outliers for ``n_params`` solved
    parameters: the parameters plus :data:`SCREEN_MIN_DOF` (the prior lowers the effective
    parameters, so a fit may screen a little earlier; this count does not rely on it)."""
    return max(n_params + SCREEN_MIN_DOF, training_rows_needed(n_params))


def samples_for_training_rows(training_rows: int, test_fraction: float) -> int:
    """The fewest samples whose training part ``n - held_out(n, test_fraction)`` (the random
    hold-out of :func:`validate`) is at least ``training_rows`` (``test_fraction`` < 1)."""
    # Below (training_rows - 0.5) / (1 - test_fraction) no n has enough training rows
    # (n - round(f n) <= n (1 - f) + 0.5): start there, so the search takes a few steps.
    n = max(training_rows, 1, int((training_rows - 0.5) / (1.0 - test_fraction)) - 1)
    while n - held_out(n, test_fraction) < training_rows:
        n += 1
    return n


def check_training_rows(n_train: int, n_included: int, n_params: int) -> None:
    """The one rule on the number of training rows: more than the ``n_params`` parameters
    solved (else the fit is exactly determined or worse), and at least
    :data:`MIN_TRAINING_SAMPLES` (:func:`training_rows_needed`).

    Raises
    ------
    calib.dataset.SampleError
        Naming the rows given, the rows needed and why.
    """
    from calib.dataset import SampleError

    need = training_rows_needed(n_params)
    if n_train >= need:
        return
    why = (
        f"identify solves {n_params} parameters here and needs more training rows than parameters"
        if need == n_params + 1
        else f"no identification trains on fewer than {MIN_TRAINING_SAMPLES} rows"
    )
    raise SampleError(
        f"samples: {n_train} training samples for identification (of {n_included} included); "
        f"need at least {need}: {why} (add samples, lower test_fraction, or fix parameters)"
    )
