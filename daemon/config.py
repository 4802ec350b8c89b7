"""Daemon configuration: one TOML file plus ``CABLECAL_*`` environment variables.

Precedence, highest first: explicit overrides (command-line options), environment variables,
the TOML file (``cablecal serve --config FILE``), the defaults below. Nested settings take
``__`` in the environment: ``CABLECAL_INDICATOR__PORT=/dev/ttyUSB1``,
``CABLECAL_SAMPLER__SETTLE_S=1.0``. The API token is ``CABLECAL_API_TOKEN``.

Every setting carries its unit in its name or its description; ``deploy/cablecal.toml.example``
lists them all with their defaults. Unknown keys in the file are errors that name the key.
"""

from __future__ import annotations

import functools
import ipaddress
import operator
import os
import secrets
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Discriminator,
    Field,
    SecretStr,
    Tag,
    field_validator,
    model_validator,
)
from pydantic_settings import (
    BaseSettings,
    PydanticBaseSettingsSource,
    SettingsConfigDict,
    TomlConfigSettingsSource,
)

from calib.monitor.stepwatch import StepSettings
from daemon.defaults import API_PORT
from daemon.sampler.config import SamplerConfig
from drivers import ROBOT_KINDS, AsciiIndicatorConfig, IndicatorConfig, ManualRobotConfig

#: Shortest accepted ``api_token`` [characters].
MIN_TOKEN_CHARS = 16

#: Sections read under their old name for one release, with a warning in the log: old name →
#: (new name, the release that stops reading the old one). CHANGELOG says the same.
DEPRECATED_SECTIONS: dict[str, tuple[str, str]] = {"drift": ("hold_check", "0.3.0")}


class ConfigError(ValueError):
    """The configuration cannot be used (names the setting)."""


def _indicator_tag(value: Any) -> str:
    kind = value.get("kind", "modbus-rtu") if isinstance(value, dict) else value.kind
    return "ascii" if kind == "ascii" else "modbus"


def _robot_tag(value: Any) -> str:
    kind = value.get("kind", "manual") if isinstance(value, dict) else value.kind
    return str(kind)


IndicatorSettings = Annotated[
    Annotated[IndicatorConfig, Tag("modbus")] | Annotated[AsciiIndicatorConfig, Tag("ascii")],
    Discriminator(_indicator_tag),
]


def _robot_settings() -> Any:
    """``[robot]``: the union of the config models of :data:`drivers.ROBOT_KINDS`, chosen by
    ``kind`` (default manual)."""
    members = [Annotated[entry.config, Tag(kind)] for kind, entry in ROBOT_KINDS.items()]
    return Annotated[functools.reduce(operator.or_, members), Discriminator(_robot_tag)]


if TYPE_CHECKING:
    RobotSettings = BaseModel
else:
    RobotSettings = _robot_settings()


class JobSettings(BaseModel):
    """Identification jobs."""

    model_config = ConfigDict(extra="forbid")

    workers: Annotated[int, Field(ge=1, le=16)] = 1
    """Worker processes of the identification pool."""
    timeout_s: Annotated[float, Field(gt=0)] = 900.0
    """A job still running after this long [s] is cancelled and marked failed."""
    noise_mm: Annotated[float, Field(gt=0)] | None = None
    """Assumed 1-sigma cable-length noise [mm] (weights the prior and the filters' R); unset:
    calib's ``noise_mm`` default (:mod:`calib.options`), the same as ``cablecal identify``."""
    worker_nice: Annotated[int, Field(ge=0, le=19)] = 10
    """Niceness added to the worker processes, so the sampler keeps its poll rate during a job."""
    worker_blas_threads: Annotated[int, Field(ge=1, le=64)] = 1
    """BLAS/OpenMP threads per worker process [count]."""
    auto_accept: bool = True
    """Accept a succeeded job's model as the robot's calibrated model when its parameters
    are physically plausible; otherwise it waits for ``POST /identifications/{id}/accept``."""
    max_pending: Annotated[int, Field(ge=1, le=1000)] = 8
    """Jobs queued or running at once; a further ``POST .../identifications`` is a 429 (each
    pending job holds its campaign's samples)."""


class RequestSettings(BaseModel):
    """Bounds of the work requests cause, the ``[requests]`` section
    (:mod:`daemon.api.http.offload`, :mod:`daemon.store.space`): the sampler's poll loop shares
    the machine with them."""

    model_config = ConfigDict(extra="forbid")

    max_filters: Annotated[int, Field(ge=1, le=16)] = 1
    """Program filters (``POST /robots/{id}/filter``) running at once, each in a worker process
    of its own (a 16 MiB upload needs up to about 1 GiB while it runs)."""
    max_queued_filters: Annotated[int, Field(ge=0, le=64)] = 2
    """Filters waiting for a free worker; a further one is a 429 with Retry-After."""
    filter_timeout_s: Annotated[float, Field(gt=0, le=86_400)] = 300.0
    """Longest a program filter may run [s]: its worker process is then killed and the answer
    is a 503 with Retry-After (a 16 MiB upload takes about 30 s on an idle 2-core PC)."""
    max_checks: Annotated[int, Field(ge=1, le=16)] = 1
    """Identification checks and submissions (``POST .../identifications``, the readiness
    route), CSV imports and exports and compensations running at once, each in a thread."""
    max_queued_checks: Annotated[int, Field(ge=0, le=256)] = 8
    """Such work waiting for its turn; a further request is a 429 with Retry-After."""
    retry_after_s: Annotated[int, Field(ge=1, le=3600)] = 5
    """The ``Retry-After`` of a 429 for work that is full [s]."""
    queue_timeout_s: Annotated[float, Field(gt=0, le=3600)] = 60.0
    """Longest wait for a free place of such work [s]; then a 503 with Retry-After (a client
    never waits behind long work without an answer)."""
    disk_reserve_mb: Annotated[float, Field(ge=0, le=1_000_000)] = 512.0
    """Free space [MiB] kept on the state directory's file system: a write that would leave
    less is refused with 507 before anything is written (0: no reserve)."""
    send_timeout_s: Annotated[float, Field(gt=0, le=3600)] = 30.0
    """A client that reads none of a response for this long [s] is disconnected (its
    buffered response freed)."""
    rate_per_s: Annotated[float, Field(ge=0, le=10_000)] = 20.0
    """REST API requests one peer address may send per second, sustained (a token bucket per
    address, :class:`daemon.api.http.guard.TokenBuckets`; a body counts one request more per
    :data:`daemon.api.http.guard.BYTES_PER_TOKEN`; ``GET /health`` is not counted); beyond it a 429
    with Retry-After (0: no limit)."""
    rate_burst: Annotated[int, Field(ge=1, le=100_000)] = 100
    """Requests one peer address may send at once above ``rate_per_s`` (the bucket's size)."""
    rate_refusal_delay_s: Annotated[float, Field(ge=0, le=10)] = 1.0
    """A request over the rate is answered (429) after this long [s], its body unread: a
    client that ignores Retry-After and sends again at once gets at most one refusal per
    connection and delay, each costing the event loop nothing while it waits."""
    campaigns_per_min: Annotated[int, Field(ge=0, le=100_000)] = 60
    """Campaigns the daemon creates per minute, from all network clients (``POST /campaigns``);
    beyond it a 429 with Retry-After (0: no limit)."""
    imports_per_min: Annotated[int, Field(ge=0, le=100_000)] = 20
    """CSV imports the daemon stores per minute, from all network clients
    (``POST /campaigns/{id}/samples/import``); beyond it a 429 with Retry-After (0: no
    limit)."""


class HoldCheckSettings(BaseModel):
    """Hold checks of a calibrated robot, the ``[hold_check]`` section
    (:mod:`daemon.monitors.holdcheck`)."""

    model_config = ConfigDict(extra="forbid")

    check_interval_h: Annotated[float, Field(gt=0)] | None = None
    """Hours between scheduled checks of every calibrated robot; unset: manual checks only."""
    threshold_mm: Annotated[float, Field(gt=0)] | None = None
    """Absolute RMS [mm] above which a check is ``not_held``; unset: ``threshold_factor`` times the
    calibration's own residual RMSE."""
    threshold_factor: Annotated[float, Field(gt=0)] = 3.0
    """Multiple of the calibration's residual RMSE used when ``threshold_mm`` is unset."""
    min_threshold_mm: Annotated[float, Field(gt=0)] = 0.01
    """Floor of the derived threshold [mm]."""
    refit_anchor: bool = False
    """Refit the anchor P0 and zero offset on the check poses (only after moving the sensor:
    it absorbs part of a change of the robot)."""
    n_poses: Annotated[int, Field(ge=3, le=100)] = 8
    """Default check poses: this many well-spread poses of the calibration's samples."""
    pose_tol_deg: Annotated[float, Field(gt=0, le=10)] = 0.5
    """A capture counts for a check pose within this on every joint [deg]."""
    timeout_s: Annotated[float, Field(gt=0)] = 1800.0
    """A check whose poses are not all captured after this long [s] fails."""


class WatchSettings(BaseModel):
    """The live sensor watch (:mod:`daemon.monitors.watch`; the test:
    :mod:`calib.monitor.stepwatch`)."""

    model_config = ConfigDict(extra="forbid")

    enabled: bool = True
    """Test each new sample against the campaign's running fit for a moved sensor."""
    min_step_mm: Annotated[float, Field(gt=0, le=100)] = StepSettings.min_step_mm
    """Smallest length change called a move [mm] (the band is at least half of it)."""
    k_sigma: Annotated[float, Field(gt=0, le=100)] = StepSettings.k_sigma
    """Band half-width in robust sigmas of the recent residuals."""
    sigma_floor_mm: Annotated[float, Field(gt=0, le=10)] = StepSettings.sigma_floor_mm
    """Floor of the residual scale [mm]."""
    min_run: Annotated[int, Field(ge=2, le=50)] = StepSettings.min_run
    """Samples beyond the band needed for an alarm: fewer are outliers."""

    def step_settings(self) -> StepSettings:
        """The pure detector's settings."""
        return StepSettings(
            min_step_mm=self.min_step_mm,
            sigma_floor_mm=self.sigma_floor_mm,
            k_sigma=self.k_sigma,
            min_run=self.min_run,
        )


def default_state_dir() -> Path:
    """``$STATE_DIRECTORY`` (set by systemd's ``StateDirectory=``), else
    ``$XDG_STATE_HOME/cablecal``, else ``~/.local/state/cablecal``."""
    if sd := os.environ.get("STATE_DIRECTORY"):
        return Path(sd.split(":")[0])
    base = os.environ.get("XDG_STATE_HOME") or str(Path.home() / ".local" / "state")
    return Path(base) / "cablecal"


class Settings(BaseSettings):
    """Everything ``cablecal serve`` reads. See the module docstring for the sources."""

    model_config = SettingsConfigDict(
        env_prefix="CABLECAL_",
        env_nested_delimiter="__",
        extra="forbid",
        validate_default=True,
    )

    host: str = "127.0.0.1"
    """Address the REST API binds to. Anything but loopback requires ``api_token``."""
    port: Annotated[int, Field(ge=0, le=65535)] = API_PORT
    """TCP port of the REST API (0: any free port)."""
    api_token: SecretStr | None = None
    """Bearer token required on every write route (``CABLECAL_API_TOKEN``), at least
    :data:`MIN_TOKEN_CHARS` characters. Unset on loopback: a random token is generated at
    start-up and written to ``STATE_DIR/api-token`` (mode 0600)."""
    public_reads: bool = False
    """Serve the read routes (GET) without a token. ``/health`` and ``/metrics`` are always
    open."""
    max_connections_per_client: Annotated[int, Field(ge=1, le=1024)] = 64
    """Connections one peer address may hold open at once; a further one is answered 503 and
    closed (the other bounds on clients: :mod:`daemon.api.http.server`)."""
    state_dir: Path = Field(default_factory=default_state_dir)
    """Directory of the SQLite database and the generated token."""
    db_path: Path | None = None
    """SQLite file; default ``STATE_DIR/cablecal.sqlite3``."""
    log_level: Literal["DEBUG", "INFO", "WARNING", "ERROR"] = "INFO"
    log_json: bool | None = None
    """JSON lines (true), human-readable (false), or JSON when stderr is not a terminal."""
    sampler: SamplerConfig = SamplerConfig()
    indicator: IndicatorSettings = Field(
        default_factory=lambda: IndicatorConfig(port="/dev/cablecal-indicator")
    )
    """The cable-length indicator; ``kind`` modbus-rtu (default), modbus-tcp or ascii."""
    robot: RobotSettings = Field(default_factory=ManualRobotConfig)
    """The joint-angle source; ``kind`` manual (default) or a key of :data:`drivers.ROBOT_KINDS`
    (huashu-socketcmd, modbus-tcp, abb-rws, ur-rtde, kuka-varproxy, fanuc-rmi)."""
    jobs: JobSettings = JobSettings()
    requests: RequestSettings = RequestSettings()
    hold_check: HoldCheckSettings = HoldCheckSettings()
    drift: HoldCheckSettings | None = Field(default=None, exclude=True)
    """Deprecated name of ``[hold_check]`` (:data:`DEPRECATED_SECTIONS`): its keys are read
    into ``hold_check``, and it stays set only so :meth:`deprecations` can warn; never read
    it for a setting."""
    watch: WatchSettings = WatchSettings()
    debug_routes: bool = False
    """Enable ``/api/v1/debug/*`` (test-only fault hooks, e.g. blocking the event loop)."""

    @field_validator("api_token")
    @classmethod
    def _token_length(cls, value: SecretStr | None) -> SecretStr | None:
        """A short token can be guessed: refuse it at load time, naming the setting."""
        if value is None or not value.get_secret_value():
            return value
        n = len(value.get_secret_value())
        if n < MIN_TOKEN_CHARS:
            raise ValueError(
                f"too short: {n} characters, at least {MIN_TOKEN_CHARS} are required "
                "(generate one with: python -c 'import secrets; print(secrets.token_hex(32))')"
            )
        return value

    @model_validator(mode="before")
    @classmethod
    def _old_section_names(cls, data: Any) -> Any:
        """A section under its deprecated name (``[drift]``, ``CABLECAL_DRIFT__*``) is read
        into its new one; a key set under both names takes the new name's value."""
        if not isinstance(data, dict):
            return data
        data = dict(data)
        for old, (new, _) in DEPRECATED_SECTIONS.items():
            if data.get(old) is None:
                continue
            legacy = data[old]
            legacy = (
                legacy.model_dump(exclude_unset=True)
                if isinstance(legacy, BaseModel)
                else dict(legacy)
            )
            current = data.get(new) or {}
            current = (
                current.model_dump(exclude_unset=True)
                if isinstance(current, BaseModel)
                else dict(current)
            )
            data[new] = {**legacy, **current}
        return data

    def deprecations(self) -> list[str]:
        """One warning per deprecated section name the configuration used, for the log."""
        return [
            f"config: [{old}] is deprecated, read as [{DEPRECATED_SECTIONS[old][0]}]; "
            f"rename it (CABLECAL_{old.upper()}__* too): [{old}] is no longer read from "
            f"{DEPRECATED_SECTIONS[old][1]}"
            for old in DEPRECATED_SECTIONS
            if getattr(self, old) is not None
        ]

    @classmethod
    def settings_customise_sources(
        cls,
        settings_cls: type[BaseSettings],
        init_settings: PydanticBaseSettingsSource,
        env_settings: PydanticBaseSettingsSource,
        dotenv_settings: PydanticBaseSettingsSource,
        file_secret_settings: PydanticBaseSettingsSource,
    ) -> tuple[PydanticBaseSettingsSource, ...]:
        return (init_settings, env_settings, TomlConfigSettingsSource(settings_cls))

    @classmethod
    def load(cls, path: str | Path | None = None, **overrides: Any) -> Settings:
        """Settings from ``path`` (TOML; None: defaults), the environment and ``overrides``.

        Raises
        ------
        ConfigError
            The file is missing or is not valid TOML.
        pydantic.ValidationError
            A value is invalid; the error names the setting.
        """
        if path is None:
            return cls(**overrides)
        p = Path(path)
        if not p.is_file():
            raise ConfigError(f"config: no such file {p}")
        import tomllib

        try:
            tomllib.loads(p.read_text(encoding="utf-8"))
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(f"config: {p} is not valid TOML: {exc}") from exc

        class _FromFile(cls):  # type: ignore[valid-type,misc]
            model_config = SettingsConfigDict(**{**cls.model_config, "toml_file": p})

        return _FromFile(**overrides)

    @property
    def database_path(self) -> Path:
        """The SQLite file."""
        return self.db_path if self.db_path is not None else self.state_dir / "cablecal.sqlite3"

    def is_loopback(self) -> bool:
        """Whether ``host`` is a loopback address (or ``localhost``)."""
        if self.host == "localhost":
            return True
        try:
            return ipaddress.ip_address(self.host).is_loopback
        except ValueError:
            return False

    def resolve_token(self) -> tuple[str, bool]:
        """The API token and whether it was generated.

        Raises
        ------
        ConfigError
            Binding to a non-loopback address without ``api_token``.
        """
        if self.api_token is not None and self.api_token.get_secret_value():
            return self.api_token.get_secret_value(), False
        if not self.is_loopback():
            raise ConfigError(
                f"api_token: required to listen on {self.host} (not loopback); "
                "set CABLECAL_API_TOKEN or api_token in the config file"
            )
        return secrets.token_urlsafe(24), True


#: ``--robot-kind`` of the two endpoints the cell had before the controller faces.
_LEGACY_READY_KEYS = {"huashu-socketcmd": "robot_socketcmd", "modbus-tcp": "robot_modbus"}


def ready_key(kind: str) -> str:
    """The READY key of the emulated face serving robot ``kind``: ``robot_socketcmd``,
    ``robot_modbus``, else ``robot_`` + the kind with ``_`` for ``-`` (``robot_ur_rtde``)."""
    return _LEGACY_READY_KEYS.get(kind) or "robot_" + kind.replace("-", "_")


def simulated_cell_overrides(
    ready: dict[str, Any], settings: Settings, robot_kind: str | None = None
) -> dict[str, Any]:
    """Indicator and robot settings pointing at a running emulated cell.

    Parameters
    ----------
    ready : dict
        The JSON of the ``READY`` line of ``cablecal simulate``: ``indicator_port`` (pty) or
        ``indicator_tcp`` (``host:port``, RTU over TCP), and the robot faces
        (``robot_socketcmd``, ``robot_modbus``, ``robot_ur_rtde``, …: ``host:port``).
    settings : Settings
        The loaded settings; serial options (baud, register map, …) are kept.
    robot_kind : str, optional
        The face the robot driver connects to: a key of :data:`drivers.ROBOT_KINDS` (not
        ``manual``). Default: ``huashu-socketcmd``, else ``modbus-tcp``.

    Raises
    ------
    ConfigError
        The mapping has no usable indicator, or no endpoint for the robot kind.
    """
    ind = settings.indicator
    ind_base = ind.model_dump() if isinstance(ind, IndicatorConfig) else {}
    if ready.get("indicator_port"):
        indicator = {**ind_base, "kind": "modbus-rtu", "port": ready["indicator_port"]}
    elif ready.get("indicator_tcp"):
        indicator = {**ind_base, "kind": "modbus-rtu", "port": f"socket://{ready['indicator_tcp']}"}
    else:
        raise ConfigError("simulated cell: READY has neither indicator_port nor indicator_tcp")
    if robot_kind is None:
        robot_kind = "huashu-socketcmd" if ready.get("robot_socketcmd") else "modbus-tcp"
        if not ready.get("robot_modbus") and not ready.get("robot_socketcmd"):
            raise ConfigError("simulated cell: READY has neither robot_socketcmd nor robot_modbus")
    kinds = [kind for kind in ROBOT_KINDS if kind != "manual"]
    if robot_kind not in kinds:
        raise ConfigError(f"--robot-kind: unknown kind {robot_kind!r}; use {', '.join(kinds)}")
    key = ready_key(robot_kind)
    if not ready.get(key):
        raise ConfigError(
            f"--robot-kind {robot_kind}: the emulated cell has no {key} endpoint "
            f"(the face is disabled in its config, or not emulated)"
        )
    host, port = str(ready[key]).rsplit(":", 1)
    robot: dict[str, Any] = {"kind": robot_kind, "host": host, "port": int(port)}
    if robot_kind == "modbus-tcp":
        robot["preset"] = "ur"
    if robot_kind == "abb-rws":
        robot.update(emulated_abb_login(settings.state_dir))
    return {"indicator": indicator, "robot": robot}


def emulated_abb_login(state_dir: Path) -> dict[str, Any]:
    """The ``[robot]`` login settings of ``serve --simulated-cell --robot-kind abb-rws``: the
    EMULATED face accepts ABB's factory-default login; its password goes to a mode-0600 file
    ``STATE_DIR/emulated-abb-rws-password`` (unless ``CABLECAL_ROBOT_PASSWORD`` is set: then
    that one is used)."""
    from drivers.abb_rws import ABB_FACTORY_PASSWORD, ABB_FACTORY_USER
    from drivers.credentials import write_secret

    if os.environ.get("CABLECAL_ROBOT_PASSWORD"):
        return {"username": ABB_FACTORY_USER}
    path = write_secret(state_dir / "emulated-abb-rws-password", ABB_FACTORY_PASSWORD)
    return {"username": ABB_FACTORY_USER, "password_file": str(path)}
