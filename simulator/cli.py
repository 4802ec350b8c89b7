"""``cablecal simulate``: registered by the emulated-cell work (issue 3)."""

from __future__ import annotations

import typer


def register(app: typer.Typer) -> None:
    """Add the ``simulate`` command to ``app`` (no command yet)."""
    del app
