"""Configuration of the emulated cell (``sim.toml``); every field has a default.

See ``docs/hardware.md`` for the reference and ``examples/sim.toml`` for a commented file.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Annotated, Final, Literal

from pydantic import BaseModel, ConfigDict, Field

from calib.default_robot import DEFAULT_ROBOT_MODEL
from drivers.indicator import RegisterMap


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class RobotSection(_Strict):
    """The emulated robot: model, true errors and motion."""

    model: str = DEFAULT_ROBOT_MODEL  # built-in name, or path to a .toml/.json model file
    dh_errors: Literal["table-xii-d1", "none"] = "table-xii-d1"
    tool_error_mm: tuple[float, float, float] = (0.8, -0.5, 1.2)
    # "random": n_poses seeded, spread poses; or a plan CSV with q1..q6 [deg] columns, or a
    # robot program (RAPID .mod, URScript, KRL .src, Fanuc .LS) whose joint moves it runs
    poses: str = "random"
    n_poses: Annotated[int, Field(ge=1)] = 60
    min_z_mm: float = 0.0  # the floor: random poses keep flange and hook point above it
    move_time_s: Annotated[float, Field(gt=0)] = 2.0
    dwell_s: Annotated[float, Field(ge=0)] = 3.0
    loop: bool = True


#: Bounds of the emulated disturbances: a sensor-stand bump per axis [mm], an offset drift
#: rate [mm/h] (fast enough for a test) and a thermal time constant [s].
MAX_ANCHOR_MOVE_MM = 500.0
MAX_DRIFT_RATE_MM_PER_H = 36000.0
MAX_DRIFT_TAU_S = 1e6


class CellSection(_Strict):
    """The drawstring sensor's true mounting."""

    anchor_mm: tuple[float, float, float] = (1400.0, 300.0, 200.0)
    offset_mm: float = -350.0
    # Emulated drift of the offset c from the start (the control port's drift_offset):
    # linear at drift_rate_mm_per_h, or with drift_tau_s > 0 a first-order approach to
    # drift_rate_mm_per_h * drift_tau_s / 3600 (a thermal time constant).
    drift_rate_mm_per_h: Annotated[
        float,
        Field(ge=-MAX_DRIFT_RATE_MM_PER_H, le=MAX_DRIFT_RATE_MM_PER_H, allow_inf_nan=False),
    ] = 0.0
    drift_tau_s: Annotated[float, Field(ge=0, le=MAX_DRIFT_TAU_S, allow_inf_nan=False)] = 0.0


#: 1σ noise of one EMULATED indicator reading [mm]: two counts of the display's last digit
#: (``decimals`` 2: 0.01 mm), so rounding does not hide it. Not a measured figure of a real
#: indicator; identify's assumed noise (:data:`calib.options.IDENTIFY_NOISE_MM`) and the
#: planner's (:data:`calib.planning.options.PLAN_NOISE_MM`) are their own defaults.
EMULATED_NOISE_MM: Final = 0.02


class IndicatorSection(_Strict):
    """The emulated HY9648 indicator."""

    mode: Literal["modbus", "ascii"] = "modbus"
    noise_mm: Annotated[float, Field(ge=0)] = EMULATED_NOISE_MM
    decimals: Annotated[int, Field(ge=0, le=3)] = 2
    range_mm: tuple[float, float] = (0.0, 2000.0)
    update_hz: Annotated[float, Field(gt=0)] = 50.0
    device_id: Annotated[int, Field(ge=1, le=247)] = 1
    baud: Annotated[int, Field(ge=300, le=921600)] = 9600
    parity: Literal["N", "E", "O"] = "N"
    stopbits: Literal[1, 2] = 1
    pty: bool = True
    pace: bool = True  # pace bytes at the baud rate on the pty
    tcp: Literal["none", "rtu", "mbap"] = "none"
    tcp_host: str = "127.0.0.1"
    tcp_port: Annotated[int, Field(ge=0, le=65535)] = 0
    ascii_rate_hz: Annotated[float, Field(gt=0)] = 10.0
    registers: RegisterMap = RegisterMap()


class ServerSection(_Strict):
    """A TCP server of the emulated cell. ``port = 0`` (the default): any free port; the
    bound port is in the READY mapping (:meth:`simulator.runner.CellRunner.ready`)."""

    enabled: bool = True
    host: str = "127.0.0.1"
    port: Annotated[int, Field(ge=0, le=65535)] = 0


#: UR's fixed RTDE port: UR's clients always connect to it.
UR_RTDE_PORT: Final = 30004


class UrRtdeSection(ServerSection):
    """The emulated UR RTDE face. UR clients always connect to port 30004, so the face keeps
    30004 and takes its own loopback address. ``host = "auto"`` (the default): the first of
    127.0.0.2 … 127.0.0.254 whose port is free (another emulated cell on this machine may
    hold 127.0.0.2:30004); the READY mapping gives the address taken."""

    host: str = "auto"
    port: Annotated[int, Field(ge=0, le=65535)] = UR_RTDE_PORT


class AbbRwsSection(ServerSection):
    """The emulated ABB Robot Web Services face (``simulator.faces.abb_rws``). ``rws``:
    ``"1.0"`` an IRC5 (HTTP, digest authentication), ``"2.0"`` an OmniCore (HTTPS, basic
    authentication; ``cert_file``/``key_file`` PEM, or a self-signed certificate generated at
    start with the ``openssl`` command). ``username``/``password``: the accepted login (ABB's
    factory default, as on a new controller; an emulator's, not a secret). Kept apart from
    ``drivers.abb_rws.ABB_FACTORY_USER`` on purpose: the simulator is written independently
    of the drivers, so a driver's wrong default fails against it."""

    rws: Literal["1.0", "2.0"] = "1.0"
    username: str = "Default User"
    password: str = "robotics"
    cert_file: str | None = None
    key_file: str | None = None


class FaultSection(_Strict):
    """Faults active from the start; all can be changed while running (control port)."""

    indicator_crc_error_rate: Annotated[float, Field(ge=0, le=1)] = 0.0
    indicator_drop_rate: Annotated[float, Field(ge=0, le=1)] = 0.0
    indicator_reply_delay_s: Annotated[float, Field(ge=0)] = 0.0
    over_range: bool = False
    robot_drop_rate: Annotated[float, Field(ge=0, le=1)] = 0.0
    robot_reply_delay_s: Annotated[float, Field(ge=0)] = 0.0
    # Emulated late replies: this fraction of robot replies is sent robot_late_delay_s late
    # (after the driver's timeout, as a congested link or a busy controller would).
    robot_late_rate: Annotated[float, Field(ge=0, le=1)] = 0.0
    robot_late_delay_s: Annotated[float, Field(ge=0)] = 0.3
    robot_frozen: bool = False


class SimConfig(_Strict):
    """The whole emulated cell."""

    seed: int = 0
    robot: RobotSection = RobotSection()
    cell: CellSection = CellSection()
    indicator: IndicatorSection = IndicatorSection()
    # The real controllers' ports (the comments) are the drivers' defaults; the emulated faces
    # take any free port instead (a test machine runs several cells), and state their own
    # facts apart from the drivers on purpose (written independently of their protocol code,
    # docs/architecture.md): a driver's wrong default then fails against its face.
    robot_socketcmd: ServerSection = ServerSection()  # real controllers: 23333
    robot_modbus: ServerSection = ServerSection()  # real UR: 502
    robot_abb_rws: AbbRwsSection = AbbRwsSection()  # real IRC5: 80, OmniCore: 443
    robot_ur_rtde: UrRtdeSection = UrRtdeSection()  # real UR: 30004
    robot_kuka_varproxy: ServerSection = ServerSection()  # real KukaVarProxy: 7000
    robot_fanuc_rmi: ServerSection = ServerSection()  # real RMI: 16001
    control: ServerSection = ServerSection()
    faults: FaultSection = FaultSection()
    base_dir: str = "."  # relative paths (model, poses) are resolved against this


#: The TCP servers whose ports :func:`with_ports` sets.
SERVER_SECTIONS = (
    "robot_socketcmd",
    "robot_modbus",
    "robot_abb_rws",
    "robot_ur_rtde",
    "robot_kuka_varproxy",
    "robot_fanuc_rmi",
    "control",
)


def load_config(path: str | Path | None) -> SimConfig:
    """Read ``sim.toml``; ``None`` gives the defaults. Relative paths in the file are
    resolved against the file's directory."""
    if path is None:
        return SimConfig()
    p = Path(path)
    data = tomllib.loads(p.read_text(encoding="utf-8"))
    data.setdefault("base_dir", str(p.parent.resolve()))
    return SimConfig.model_validate(data)


def with_ports(config: SimConfig, **ports: int | None) -> SimConfig:
    """``config`` with the TCP ports of the named servers (``robot_socketcmd``,
    ``robot_modbus``, ``control``) replaced; ``None`` keeps the config's port, 0 asks for any
    free port. Raises ``ValueError`` for an unknown server name or a port out of 0..65535."""
    data = config.model_dump()
    for key, port in ports.items():
        if key not in SERVER_SECTIONS:
            raise ValueError(f"unknown server {key!r}; known: {list(SERVER_SECTIONS)}")
        if port is not None:
            data[key]["port"] = port
    return SimConfig.model_validate(data)
