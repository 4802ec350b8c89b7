"""Fixtures of the store tests: a fresh store on a temporary file, and a campaign in it."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import typer
from _store_helpers import ROBOT

from daemon.cli import db as cli_db
from daemon.store import Store


@pytest.fixture
def store(tmp_path: Path) -> Iterator[Store]:
    s = Store(tmp_path / "state" / "cablecal.sqlite3")
    yield s
    s.close()


@pytest.fixture
def campaign(store: Store) -> dict[str, Any]:
    robot = store.ensure_builtin_robot(ROBOT)
    return store.create_campaign("cell 1", robot["id"], notes="test")


@pytest.fixture
def cli() -> typer.Typer:
    """A typer app with only ``cablecal db``."""
    app = typer.Typer()

    @app.callback()
    def root() -> None:
        """cablecal (test root)."""

    cli_db.register(app)
    return app
