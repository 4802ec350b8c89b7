"""``cablecal simulate``: run the emulated cell until interrupted.

The simulator owns its entry (:func:`simulator.entry.run`, also ``python -m simulator``);
this command calls it. The simulator (pymodbus) is imported when the command runs, not when
the command line is built.
"""

from pathlib import Path

import typer

#: ``cablecal simulate --help``: one string per paragraph (typer's rich help keeps a line
#: break inside a paragraph, and it would break the text mid-sentence at 80 columns).
SIMULATE_HELP = (
    "Run the emulated cell (indicator on a pty, robot controllers on TCP).\n\n"
    "Prints one line 'READY {json}' with the endpoints, then serves until SIGINT/SIGTERM. "
    "The ports given here override the config file's; unset ports are free ports chosen at "
    "start."
)


def simulate(
    config: Path | None = typer.Option(
        None, "--config", "-c", help="sim.toml (see docs/hardware.md); defaults when omitted"
    ),
    verbose: bool = typer.Option(False, "--verbose", "-v", help="log protocol events"),
    socketcmd_port: int | None = typer.Option(
        None, min=0, max=65535, help="TCP port of the emulated Huashu SocketCmd (0: any free)"
    ),
    modbus_port: int | None = typer.Option(
        None, min=0, max=65535, help="TCP port of the emulated Modbus-TCP robot (0: any free)"
    ),
    control_port: int | None = typer.Option(
        None, min=0, max=65535, help="TCP port of the emulated cell's control port (0: any free)"
    ),
) -> None:
    """Run the emulated cell until SIGINT/SIGTERM (``--help``: :data:`SIMULATE_HELP`)."""
    from simulator.entry import run

    run(
        config,
        verbose=verbose,
        socketcmd_port=socketcmd_port,
        modbus_port=modbus_port,
        control_port=control_port,
    )


def register(app: typer.Typer) -> None:
    """Add the ``simulate`` command to ``app``."""
    app.command("simulate", help=SIMULATE_HELP)(simulate)
