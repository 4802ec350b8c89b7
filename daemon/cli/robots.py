"""``cablecal robots``: the robot library (:mod:`calib.robots`) on the command line.

``cablecal robots`` lists the built-in arms (name, maker, the maker's designation, reach and
payload); ``cablecal robots show NAME`` prints one arm's model file exactly as stored, the
text ``--robot FILE.toml`` takes (``--robot NAME`` takes the name itself). An unknown name:
exit 2, naming the known ones.
"""

from typing import Annotated

import typer
from rich import box
from rich.console import Console
from rich.table import Table

from daemon.cli.errors import fail

robots_app = typer.Typer(
    name="robots",
    help="The built-in robot arms: list them, or print one as a model file.",
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


def register(app: typer.Typer) -> None:
    """Add the ``robots`` command group to ``app``."""
    app.add_typer(robots_app, name="robots")
