"""``cablecal simulate``: run the emulated cell until interrupted (also ``python -m simulator``).

The simulator (pymodbus) is imported when the command runs, not when the command line is built.
"""

from __future__ import annotations

from pathlib import Path

import typer


def simulate(
    config: Path | None = typer.Option(
        None, "--config", "-c", help="sim.toml (see docs/hardware.md); defaults when omitted"
    ),
    verbose: bool = typer.Option(False, "--verbose", "-v", help="log protocol events"),
) -> None:
    """Run the emulated cell (indicator on a pty, robot controllers on TCP).

    Prints one line ``READY {json}`` with the endpoints, then serves until SIGINT/SIGTERM.
    """
    import asyncio
    import logging

    from simulator.config import load_config
    from simulator.runner import serve_forever

    logging.basicConfig(level=logging.DEBUG if verbose else logging.WARNING)
    asyncio.run(serve_forever(load_config(config)))


def register(app: typer.Typer) -> None:
    """Add the ``simulate`` command to ``app``."""
    app.command("simulate")(simulate)
