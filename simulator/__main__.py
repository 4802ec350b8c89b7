"""``python -m simulator [--config sim.toml]``: same as ``cablecal simulate``."""

from __future__ import annotations

import typer

from daemon.cli.simulate import simulate

if __name__ == "__main__":
    typer.run(simulate)
