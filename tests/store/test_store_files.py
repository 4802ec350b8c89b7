"""The database's files on disk: their modes, and ``cablecal db export --out`` never writing
onto the database or any other SQLite file."""

from __future__ import annotations

import os
import stat
from collections.abc import Iterator
from pathlib import Path

import pytest
import typer
from _store_helpers import ROBOT, csv_text, import_csv
from typer.testing import CliRunner

from daemon.cli import db as cli_db
from daemon.store import Store


def mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


@pytest.fixture
def umask_022() -> Iterator[None]:
    """The usual interactive umask (files 0644 by default), restored afterwards."""
    old = os.umask(0o022)
    try:
        yield
    finally:
        os.umask(old)


@pytest.mark.usefixtures("umask_022")
def test_new_database_and_its_wal_and_shm_are_not_world_readable(tmp_path: Path) -> None:
    path = tmp_path / "state" / "cablecal.sqlite3"
    with Store(path) as s:
        robot = s.ensure_builtin_robot(ROBOT)
        s.create_campaign("modes", robot["id"])
        wal, shm = Path(f"{path}-wal"), Path(f"{path}-shm")
        assert wal.exists() and shm.exists()
        modes = {p.name: oct(mode(p)) for p in (path, wal, shm)}
        assert set(modes.values()) == {"0o640"}, modes


def test_a_strict_umask_is_kept(tmp_path: Path) -> None:
    old = os.umask(0o077)
    try:
        path = tmp_path / "cablecal.sqlite3"
        with Store(path) as s:
            s.ensure_builtin_robot(ROBOT)
            assert mode(path) == 0o600
            assert mode(Path(f"{path}-wal")) == 0o600
    finally:
        os.umask(old)


@pytest.mark.usefixtures("umask_022")
def test_an_old_world_readable_database_is_restricted_on_open(tmp_path: Path) -> None:
    path = tmp_path / "cablecal.sqlite3"
    with Store(path) as s:
        s.ensure_builtin_robot(ROBOT)
    os.chmod(path, 0o644)  # as a database created before modes were set
    with Store(path) as s:
        s.ensure_builtin_robot(ROBOT)
        assert mode(path) == 0o640
        assert mode(Path(f"{path}-wal")) == 0o640
    with Store(path, readonly=True):
        assert mode(path) == 0o640


# ------------------------------------------------------------------------- db export --out
@pytest.fixture
def database(tmp_path: Path) -> tuple[Path, int]:
    path = tmp_path / "db.sqlite3"
    with Store(path) as s:
        cid = int(s.create_campaign("line 3", s.ensure_builtin_robot(ROBOT)["id"])["id"])
        import_csv(s, cid, csv_text(12, groups=True))
    return path, cid


def export(cli: typer.Typer, db: Path, cid: int, out: Path) -> tuple[int, str]:
    result = CliRunner().invoke(cli, ["db", "export", str(cid), "--db", str(db), "--out", str(out)])
    return result.exit_code, result.output


def unchanged(path: Path, before: bytes) -> bool:
    with Store(path, readonly=True) as s:
        return path.read_bytes() == before and s.integrity_check() == "ok"


@pytest.mark.parametrize("how", ["same path", "relative path", "symlink", "hard link"])
def test_export_refuses_to_overwrite_the_database(
    tmp_path: Path,
    cli: typer.Typer,
    database: tuple[Path, int],
    monkeypatch: pytest.MonkeyPatch,
    how: str,
) -> None:
    db, cid = database
    before = db.read_bytes()
    out = db
    if how == "relative path":
        monkeypatch.chdir(tmp_path)
        out = Path(".") / "sub" / ".." / db.name
        (tmp_path / "sub").mkdir()
    elif how == "symlink":
        out = tmp_path / "export.csv"
        out.symlink_to(db)
    elif how == "hard link":
        out = tmp_path / "export.csv"
        os.link(db, out)
    code, output = export(cli, db, cid, out)
    assert code == cli_db.EXIT_NOT_FOUND, output
    assert "is the database" in output and "refusing to overwrite" in output
    assert unchanged(db, before)


def test_export_refuses_the_wal_file_and_any_other_sqlite_file(
    tmp_path: Path, cli: typer.Typer, database: tuple[Path, int]
) -> None:
    db, cid = database
    other = tmp_path / "other.sqlite3"
    with Store(other) as s:
        s.ensure_builtin_robot(ROBOT)
    before = other.read_bytes()
    code, output = export(cli, db, cid, other)
    assert code == cli_db.EXIT_NOT_FOUND, output
    assert "is an SQLite database" in output
    assert unchanged(other, before)

    with Store(db) as s:  # open read-write: the WAL file exists while it is open
        wal = Path(f"{db}-wal")
        assert wal.exists()
        wal_before = wal.read_bytes()
        code, output = export(cli, db, cid, wal)
        assert code == cli_db.EXIT_NOT_FOUND, output
        assert "-wal file" in output
        assert wal.read_bytes() == wal_before
        s.ensure_builtin_robot(ROBOT)


def test_export_overwrites_an_ordinary_file(
    tmp_path: Path, cli: typer.Typer, database: tuple[Path, int]
) -> None:
    db, cid = database
    out = tmp_path / "old.csv"
    out.write_text("an older export\n", encoding="utf-8")
    code, output = export(cli, db, cid, out)
    assert code == 0, output
    assert out.read_text(encoding="utf-8").startswith("q1,q2,q3,q4,q5,q6,L")
    assert len(out.read_text(encoding="utf-8").splitlines()) == 13
