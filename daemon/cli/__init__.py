"""The ``cablecal`` command line: one typer app; each part registers its own commands.

The command modules registered here do not use ``from __future__ import annotations``: typer
reads every command's signature when it builds the command line (also for ``--help``), and
string annotations would have to be compiled and evaluated one by one at every start. Names
imported only for type checking are quoted.
"""

from __future__ import annotations

from daemon.process.blas import single_threaded_blas, steady_heap

single_threaded_blas()  # before anything imports numpy (daemon.process.blas says why)
steady_heap()

import typer  # noqa: E402

app = typer.Typer(
    name="cablecal",
    help="Robot calibration with a drawstring sensor: identify, compare, simulate, serve.",
    no_args_is_help=True,
    add_completion=False,
)


def _register_all() -> None:
    from daemon.cli import (
        apply,
        calibration,
        db,
        filter,
        plan,
        program,
        report,
        robots,
        serve,
        simulate,
    )

    calibration.register(app)
    plan.register(app)
    apply.register(app)
    filter.register(app)
    program.register(app)
    report.register(app)
    serve.register(app)
    db.register(app)
    simulate.register(app)
    robots.register(app)


_register_all()


def main() -> None:
    """Console-script entry point."""
    app()
