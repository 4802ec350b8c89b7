"""``cablecal robots``: the robot library (:mod:`calib.robots`) on the command line.

``cablecal robots`` lists the built-in arms (name, maker, the maker's designation, reach and
payload); ``cablecal robots show NAME`` prints one arm's model file exactly as stored, the
text ``--robot FILE.toml`` takes (``--robot NAME`` takes the name itself). An unknown name:
exit 2, naming the known ones. ``cablecal robots from-ur HOST`` prints a Universal Robots
arm's own model file: the table its controller computes with (its factory calibration, read
from the primary interface's KinematicsInfo, :mod:`drivers.ur_primary`), with the library
arm's joint ranges and convention (:mod:`calib.robots.ur_factory`).
"""

from typing import Annotated

import typer
from rich import box
from rich.console import Console
from rich.table import Table

from daemon.cli.errors import fail

robots_app = typer.Typer(
    name="robots",
    help="The built-in robot arms: list them, print one as a model file, or read a UR arm's own.",
    add_completion=False,
    invoke_without_command=True,
)


def _number(value: float | None) -> str:
    return "-" if value is None else f"{value:g}"


@robots_app.callback()
def list_robots(ctx: typer.Context) -> None:
    """List the built-in arms (``--robot NAME`` takes the name)."""
    if ctx.invoked_subcommand is not None:
        return
    from calib.robots import library_info, library_names

    table = Table(title="Built-in robots (--robot NAME)", title_justify="left", box=box.SIMPLE_HEAD)
    table.add_column("Name", no_wrap=True)
    table.add_column("Maker")
    table.add_column("Model", no_wrap=True)
    table.add_column("Reach mm", justify="right")
    table.add_column("Payload kg", justify="right")
    for name in library_names():
        info = library_info(name)
        table.add_row(
            name,
            info.maker or "-",
            info.title or "-",
            _number(info.reach_mm),
            _number(info.payload_kg),
        )
    Console(highlight=False).print(table)


@robots_app.command("show")
def show_robot(
    name: Annotated[str, typer.Argument(help="A name from `cablecal robots`", metavar="NAME")],
) -> None:
    """Print arm NAME as a model file (the format --robot FILE.toml takes)."""
    from calib.robots import LibraryError, library_text

    try:
        text = library_text(name)
    except LibraryError as exc:
        raise fail(exc.message) from None
    typer.echo(text, nl=not text.endswith("\n"))


@robots_app.command("from-ur")
def from_ur(
    host: Annotated[str, typer.Argument(help="The UR controller's address", metavar="HOST")],
    port: Annotated[
        int | None,
        typer.Option(help="Its primary interface port; default: UR's own.", min=1, max=65535),
    ] = None,
    base: Annotated[
        str | None,
        typer.Option(help="The library arm it is (ur10e …); default: the one its table fits."),
    ] = None,
    name: Annotated[str | None, typer.Option(help="The model's name; default: BASE-factory.")] = (
        None
    ),
    timeout_s: Annotated[
        float, typer.Option("--timeout-s", help="Give up after this long.", min=0.1)
    ] = 5.0,
) -> None:
    """Print a UR arm's own model file: the table its controller computes with."""
    import asyncio

    from calib.export import model_to_toml
    from calib.models import ModelError, builtin_model
    from calib.robots.ur_factory import from_kinematics_info, library_ur_arm
    from drivers.ur_primary import PRIMARY_PORT, PrimaryInterfaceError, read_kinematics_info

    port = PRIMARY_PORT if port is None else port
    try:
        info = asyncio.run(read_kinematics_info(host, port, timeout_s))
    except PrimaryInterfaceError as exc:
        raise fail(str(exc)) from None
    except OSError as exc:
        raise fail(f"{host}:{port}: cannot connect: {exc.strerror or exc}") from None
    try:
        base_name = base or library_ur_arm(info.a_m, info.d_m)
        arm = from_kinematics_info(
            builtin_model(base_name), info.theta_rad, info.a_m, info.d_m, info.alpha_rad, name
        )
    except ModelError as exc:
        raise fail(str(exc)) from None
    comment = (
        f"The arm at {host}:{port} as its controller computes (KinematicsInfo of its primary "
        f"interface: calibration status {info.calibration_status}, checksums "
        f"{' '.join(f'{c:08x}' for c in info.checksums)}), with the joint ranges and "
        f"convention of {base_name} (cablecal robots from-ur; docs/robots-ur.md)."
    )
    typer.echo(model_to_toml(arm, [comment]), nl=False)


def register(app: typer.Typer) -> None:
    """Add the ``robots`` command group to ``app``."""
    app.add_typer(robots_app, name="robots")
