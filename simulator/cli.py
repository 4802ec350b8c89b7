"""``cablecal simulate``: run the emulated cell until interrupted."""

from __future__ import annotations

import asyncio
import logging
from pathlib import Path

import typer

from simulator.config import SimConfig, load_config
from simulator.runner import serve_forever


def _port_option(what: str) -> int | None:
    return typer.Option(  # type: ignore[no-any-return]
        None, min=0, max=65535, help=f"TCP port of the emulated {what} (0: any free port); "
        "overrides the config"
    )  # fmt: skip


def simulate(
    config: Path | None = typer.Option(
        None, "--config", "-c", help="sim.toml (see docs/hardware.md); defaults when omitted"
    ),
    socketcmd_port: int | None = _port_option("Huashu SocketCmd controller"),
    modbus_port: int | None = _port_option("UR-style Modbus TCP controller"),
    control_port: int | None = _port_option("cell's control port"),
    verbose: bool = typer.Option(False, "--verbose", "-v", help="log protocol events"),
) -> None:
    """Run the EMULATED cell (indicator on a pty, robot controllers on TCP).

    TCP ports are free ones unless set in the config or here. Prints the endpoints on stderr
    and one line ``READY {json}`` with them on stdout, then serves until SIGINT/SIGTERM.
    """
    logging.basicConfig(level=logging.DEBUG if verbose else logging.WARNING)
    cfg = load_config(config)
    data = cfg.model_dump()
    for key, port in (
        ("robot_socketcmd", socketcmd_port),
        ("robot_modbus", modbus_port),
        ("control", control_port),
    ):
        if port is not None:
            data[key]["port"] = port
    cfg = SimConfig.model_validate(data)
    asyncio.run(serve_forever(cfg))


def register(app: typer.Typer) -> None:
    """Add the ``simulate`` command to ``app``."""
    app.command("simulate")(simulate)
