"""The simulator's own entry: run the EMULATED cell until interrupted.

``python -m simulator`` parses its command line here (:func:`main`); ``cablecal simulate``
(``daemon/cli/simulate.py``) has the same options and calls :func:`run`. The simulator never
imports the daemon.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
from collections.abc import Sequence
from pathlib import Path

from simulator.config import load_config, with_ports
from simulator.runner import serve_forever

#: The largest TCP port number.
MAX_PORT = 65535


def run(
    config: Path | None,
    *,
    verbose: bool = False,
    socketcmd_port: int | None = None,
    modbus_port: int | None = None,
    control_port: int | None = None,
) -> None:
    """Run the cell of ``config`` (``sim.toml``; None: the defaults) until SIGINT/SIGTERM.
    Prints ``READY {json}`` once bound. The ports given override the file's (0: any free)."""
    logging.basicConfig(level=logging.DEBUG if verbose else logging.WARNING)
    cfg = with_ports(
        load_config(config),
        robot_socketcmd=socketcmd_port,
        robot_modbus=modbus_port,
        control=control_port,
    )
    asyncio.run(serve_forever(cfg))


def _port(text: str) -> int:
    """A TCP port 0..65535 (0: any free), for argparse."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a whole number: {text!r}") from None
    if not 0 <= value <= MAX_PORT:
        raise argparse.ArgumentTypeError(f"{value} is not in 0..{MAX_PORT}")
    return value


def main(argv: Sequence[str] | None = None) -> None:
    """``python -m simulator [--config sim.toml] [-v] [--socketcmd-port N] …``."""
    parser = argparse.ArgumentParser(
        prog="python -m simulator",
        description="Run the EMULATED cell (indicator on a pty, robot controllers on TCP); "
        "prints one line 'READY {json}' with the endpoints, then serves until SIGINT/SIGTERM. "
        "Same as 'cablecal simulate'.",
    )
    parser.add_argument("--config", "-c", type=Path, help="sim.toml (see docs/hardware.md)")
    parser.add_argument("--verbose", "-v", action="store_true", help="log protocol events")
    for name, what in (
        ("socketcmd", "the emulated Huashu SocketCmd"),
        ("modbus", "the emulated Modbus-TCP robot"),
        ("control", "the emulated cell's control port"),
    ):
        parser.add_argument(f"--{name}-port", type=_port, help=f"TCP port of {what} (0: any free)")
    args = parser.parse_args(argv)
    run(
        args.config,
        verbose=args.verbose,
        socketcmd_port=args.socketcmd_port,
        modbus_port=args.modbus_port,
        control_port=args.control_port,
    )
