"""``cablecal program``: joint targets (a plan, or compensated targets) as a robot program.

The formats come from :mod:`calib.programs.formats` (standard library only, so ``--help``
stays light); the writers, the robot model and the daemon's settings are imported inside the
command. The default dwell follows the sampler's ``settle_s`` as the daemon's settings give it
(``--config``, ``CABLECAL_SAMPLER__SETTLE_S`` or the default), through
:func:`calib.programs.formats.dwell_s_for_settle`.
"""

from enum import Enum
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from calib.default_robot import DEFAULT_ROBOT_MODEL
from calib.programs.formats import DEFAULT_SPEED_PCT, PROGRAM_FORMATS, SUFFIX, TITLE
from daemon.cli.errors import fail as _fail

#: ``--format``'s choice, built from the one list of formats.
ProgramFormat = Enum("ProgramFormat", {f.replace("-", "_"): f for f in PROGRAM_FORMATS}, type=str)  # type: ignore[misc]

PROGRAM_HELP = (
    "Write joint targets (a plan from 'cablecal plan', or 'cablecal compensate' output) as a "
    "robot program: each target a joint move to a fine stop, then a dwell for the sampler. "
    "Formats: " + ", ".join(f"{f} ({TITLE[f]}, {SUFFIX[f]})" for f in PROGRAM_FORMATS) + "."
)

#: Formats whose controller finds the program by its file name (KRL's DEF, Fanuc's /PROG).
_NAME_IS_FILE = ("krl", "fanuc-ls")


def program_cmd(
    targets: Annotated[Path, typer.Argument(help="Joint-target CSV with q1..q6 [deg]")],
    fmt: Annotated[ProgramFormat, typer.Option("--format", help="Controller language")],
    out: Annotated[Path, typer.Option(help="Write the program here")],
    speed_pct: Annotated[
        float, typer.Option(help="Joint speed [% of the robot's maximum], 1..100")
    ] = DEFAULT_SPEED_PCT,
    dwell_s: Annotated[
        float | None,
        typer.Option(help="Wait at each target [s] (default: from the sampler's settle_s)"),
    ] = None,
    robot: Annotated[
        str, typer.Option(help="Built-in model name or model .toml/.json (joint limits)")
    ] = DEFAULT_ROBOT_MODEL,
    name: Annotated[
        str | None, typer.Option(help="Program name (default: from the --out file name)")
    ] = None,
    config: Annotated[
        Path | None, typer.Option("--config", "-c", help="The daemon's TOML settings")
    ] = None,
    anchor: Annotated[
        str | None,
        typer.Option(help="A plan for several sensor anchors: this anchor's poses only"),
    ] = None,
) -> None:
    """Write the targets as a robot program (help: :data:`PROGRAM_HELP`)."""
    from calib.models import ModelError
    from calib.programs.common import ProgramError
    from calib.programs.formats import dwell_s_for_settle
    from calib.programs.registry import build_program, name_rule
    from daemon.config import ConfigError, Settings
    from daemon.datafiles import load_robot

    fmt_name = str(fmt.value)
    try:
        model = load_robot(robot)
    except (ModelError, KeyError, ValueError) as exc:
        raise _fail(f"--robot: {exc}") from None
    if dwell_s is None:
        try:
            settle_s = Settings.load(config).sampler.settle_s
        except (ConfigError, ValueError, OSError) as exc:
            raise _fail(f"--config: {exc}") from None
        dwell_s = dwell_s_for_settle(settle_s)
    rule = name_rule(fmt_name)
    prog_name = name if name is not None else rule.from_text(out.stem)
    note = None
    if fmt_name in _NAME_IS_FILE and prog_name.lower() != out.stem.lower():
        note = (
            f"note: the controller finds a {TITLE[fmt_name]} program by its file name; "
            f"rename the file {prog_name}{SUFFIX[fmt_name]} before loading it"
        )
    try:
        text = targets.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise _fail(f"{targets}: cannot read: {exc}") from None
    try:
        program, body = build_program(
            text,
            fmt=fmt_name,
            name=prog_name,
            robot_name=model.name,
            limits_deg=model.limits_deg().tolist(),
            speed_pct=speed_pct,
            dwell_s=dwell_s,
            what=f"program of {targets.name}",
            source=str(targets),
            anchor=anchor,
        )
    except ProgramError as exc:
        message = str(exc)
        raise _fail("--" + message if message.startswith("anchor:") else message) from None
    out.write_text(body, encoding="utf-8", newline="")  # the language's own line ends
    console = Console()
    console.print(
        f"wrote {out}: {program.name}, {len(program.joints_deg)} targets, "
        f"speed {program.speed_pct:g} %, dwell {program.dwell_s:g} s",
        highlight=False,
    )
    if note:
        console.print(note, highlight=False)


EMULATED_RUN_HELP = (
    "Make the EMULATED robot run a program (any format of 'cablecal program', or a plan CSV): "
    "it moves through the program's joint targets in order with the emulated cell's own move "
    "and dwell times. --control is the cell's control endpoint ('make run' prints it)."
)


def emulated_robot_run_cmd(
    program: Annotated[Path, typer.Argument(help="Robot program or plan CSV")],
    control: Annotated[str, typer.Option(help="The EMULATED cell's control port HOST:PORT")],
    loop: Annotated[bool, typer.Option(help="Repeat the program")] = False,
) -> None:
    """Load ``program`` into the emulated robot (help: :data:`EMULATED_RUN_HELP`)."""
    from simulator.runner import ControlClient

    host, _, port = control.rpartition(":")
    if not host or not port.isdigit():
        raise _fail(f"--control: expected HOST:PORT, got {control!r}")
    try:
        text = program.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise _fail(f"{program}: cannot read it as UTF-8 text: {exc}") from None
    try:
        client = ControlClient(control)
    except OSError as exc:
        raise _fail(f"--control {control}: cannot connect: {exc}") from None
    try:  # the text: the cell reads files only inside its own config directory
        reply = client("load_poses", text=text, loop=loop)
    except RuntimeError as exc:
        raise _fail(str(exc)) from None
    finally:
        client.close()
    Console().print(
        f"the EMULATED robot runs {program.name}: {len(reply['poses_deg'])} targets"
        + (", repeated" if reply["loop"] else ""),
        highlight=False,
    )


def register(app: typer.Typer) -> None:
    """Add ``program`` and ``emulated-robot-run`` to ``app``."""
    app.command("program", help=PROGRAM_HELP)(program_cmd)
    app.command("emulated-robot-run", help=EMULATED_RUN_HELP)(emulated_robot_run_cmd)
