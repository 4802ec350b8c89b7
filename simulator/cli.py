"""``cablecal simulate``: run the emulated cell until interrupted."""

from __future__ import annotations

import asyncio
import logging
from pathlib import Path

import typer

from simulator.config import load_config
from simulator.runner import serve_forever


def simulate(
    config: Path | None = typer.Option(
        None, "--config", "-c", help="sim.toml (see docs/hardware.md); defaults when omitted"
    ),
    verbose: bool = typer.Option(False, "--verbose", "-v", help="log protocol events"),
) -> None:
    """Run the emulated cell (indicator on a pty, robot controllers on TCP).

    Prints one line ``READY {json}`` with the endpoints, then serves until SIGINT/SIGTERM.
    """
    logging.basicConfig(level=logging.DEBUG if verbose else logging.WARNING)
    asyncio.run(serve_forever(load_config(config)))


def register(app: typer.Typer) -> None:
    """Add the ``simulate`` command to ``app``."""
    app.command("simulate")(simulate)
