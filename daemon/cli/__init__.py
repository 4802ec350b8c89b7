"""The ``cablecal`` command line: one typer app; each part registers its own commands."""

from __future__ import annotations

import typer

app = typer.Typer(
    name="cablecal",
    help="Robot calibration with a drawstring sensor: identify, compare, simulate, serve.",
    no_args_is_help=True,
    add_completion=False,
)


def _register_all() -> None:
    import daemon.cli_calib as cli_calib
    import daemon.cli_db as cli_db
    import daemon.cli_serve as cli_serve
    from simulator import cli as simulator_cli

    cli_calib.register(app)
    cli_serve.register(app)
    cli_db.register(app)
    simulator_cli.register(app)


_register_all()


def main() -> None:
    """Console-script entry point."""
    app()
