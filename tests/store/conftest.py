"""Fixtures of the store tests: a fresh store on a temporary file, and a campaign in it."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from _store_helpers import ROBOT

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
