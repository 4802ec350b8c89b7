"""``cablecal db``: the daemon's SQLite database from the command line.

``cablecal db export CAMPAIGN --format csv|json [--db PATH] [--out FILE]``. The CSV is the
format ``cablecal identify`` reads (included samples only); the JSON has the campaign, its
robot and every sample with std, count, timestamps and the excluded flag.

The file is opened read-only, so exporting next to a running daemon is safe (WAL readers do
not block the writer). ``--out`` never overwrites the database (nor its WAL or shared-memory
file, also through a symlink or a hard link) or any other SQLite file: exit 2, nothing written.

The store (sqlite-utils) is imported when the command runs, not when the command line is built.
"""

import enum
import json
import os
import stat
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.markup import escape

from daemon.cli.errors import fail as _fail
from daemon.cli.errors import printable

err_console = Console(stderr=True)

EXIT_NOT_FOUND = 2  # no such campaign, or a bad argument
EXIT_DB_ERROR = 1  # the database cannot be opened or read

#: The first 16 bytes of every SQLite 3 database file.
SQLITE_HEADER = b"SQLite format 3\x00"

db_app = typer.Typer(
    name="db",
    help="The daemon's SQLite database: export campaigns.",
    no_args_is_help=True,
    add_completion=False,
)


class ExportFormat(enum.StrEnum):
    """Output formats of ``db export``."""

    csv = "csv"
    json = "json"


def _database_path(db: Path | None, config: Path | None) -> Path:
    """``--db``, else the daemon's setting (``--config`` file, ``CABLECAL_*`` variables)."""
    if db is not None:
        return db
    from daemon.config import Settings  # the daemon's settings; only needed without --db

    return Settings.load(config).database_path


def _same_file(a: os.stat_result, b: Path) -> bool:
    try:
        other = b.stat()
    except OSError:
        return False
    return (a.st_dev, a.st_ino) == (other.st_dev, other.st_ino)


def refuse_output(out: Path, database: Path) -> str | None:
    """Why ``--out`` must not be written, or None: it is the database itself or one of its
    ``-wal``/``-shm``/``-journal`` files (compared by device and inode, so a symlink or a hard
    link is caught too), or any SQLite database (its first 16 bytes)."""
    from daemon.store.db import SIDE_FILE_SUFFIXES

    try:
        st = out.stat()
    except FileNotFoundError:
        return None
    except OSError as exc:
        return f"--out {out}: {exc.strerror}"
    for suffix in ("", *SIDE_FILE_SUFFIXES):
        if _same_file(st, database.with_name(database.name + suffix)):
            what = "the database" if not suffix else f"the database's {suffix} file"
            return f"--out {out} is {what} {database}; refusing to overwrite it"
    if stat.S_ISREG(st.st_mode):
        try:
            with out.open("rb") as f:
                header = f.read(len(SQLITE_HEADER))
        except OSError as exc:
            return f"--out {out}: {exc.strerror}"
        if header == SQLITE_HEADER:
            return f"--out {out} is an SQLite database; refusing to overwrite it"
    return None


@db_app.command("export")
def export_cmd(
    campaign: Annotated[str, typer.Argument(help="Campaign id, or its name if unique")],
    fmt: Annotated[
        ExportFormat,
        typer.Option("--format", "-f", help="csv (what `cablecal identify` reads) or json"),
    ] = ExportFormat.csv,
    db: Annotated[
        Path | None,
        typer.Option(
            "--db",
            envvar="CABLECAL_DB_PATH",
            help="SQLite file (default: the daemon's, from --config and CABLECAL_* variables)",
        ),
    ] = None,
    config: Annotated[
        Path | None, typer.Option(help="Daemon config TOML, to find the database without --db")
    ] = None,
    out: Annotated[Path | None, typer.Option(help="Write here instead of stdout")] = None,
    raw: Annotated[bool, typer.Option(help="JSON: include each capture's raw readings")] = False,
) -> None:
    """Export a campaign's samples as CSV or JSON."""
    from daemon.store import Store, StoreError, StoreInvalid, StoreNotFound

    try:
        path = _database_path(db, config)
    except ValueError as exc:  # ConfigError and pydantic's ValidationError
        raise _fail(f"configuration: {exc}", EXIT_NOT_FOUND) from None
    if out is not None and (refusal := refuse_output(out, path)) is not None:
        raise _fail(refusal, EXIT_NOT_FOUND)
    try:
        with Store(path, readonly=True) as store:
            found = store.find_campaign(campaign)
            if fmt is ExportFormat.csv:
                text = store.export_csv(int(found["id"]))
            else:
                data = store.export_json(int(found["id"]), include_raw=raw)
                text = json.dumps(data, indent=2) + "\n"
    except (StoreNotFound, StoreInvalid) as exc:
        raise _fail(f"{path}: {exc}", EXIT_NOT_FOUND) from None
    except StoreError as exc:
        raise _fail(str(exc), EXIT_DB_ERROR) from None
    if out is None:
        typer.echo(printable(text), nl=False)  # CSV cells may be old rows with controls
        return
    try:
        out.write_text(text, encoding="utf-8")
    except OSError as exc:
        raise _fail(f"cannot write {out}: {exc.strerror}", EXIT_DB_ERROR) from None
    n = found["n_included"] if fmt is ExportFormat.csv else found["n_samples"]
    err_console.print(
        escape(printable(f"wrote {out}: campaign {found['id']} ({found['name']}), {n} samples")),
        soft_wrap=True,
    )


def register(app: typer.Typer) -> None:
    """Add the ``db`` command group to ``app``."""
    app.add_typer(db_app, name="db")
