"""``cablecal db``: the daemon's SQLite database from the command line.

``cablecal db export CAMPAIGN --format csv|json [--db PATH] [--out FILE]``. The CSV is the
format ``cablecal identify`` reads (included samples only); the JSON has the campaign, its
robot and every sample with std, count, timestamps and the excluded flag.

The file is opened read-only, so exporting next to a running daemon is safe (WAL readers do
not block the writer).

The store (sqlite-utils) is imported when the command runs, not when the command line is built.
"""

from __future__ import annotations

import enum
import json
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.markup import escape

err_console = Console(stderr=True)

EXIT_NOT_FOUND = 2  # no such campaign, or a bad argument
EXIT_DB_ERROR = 1  # the database cannot be opened or read

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


def _fail(message: str, code: int) -> typer.Exit:
    err_console.print(f"[bold red]error:[/] {escape(message)}", soft_wrap=True)
    return typer.Exit(code)


def _database_path(db: Path | None, config: Path | None) -> Path:
    """``--db``, else the daemon's setting (``--config`` file, ``CABLECAL_*`` variables)."""
    if db is not None:
        return db
    from daemon.config import Settings  # the daemon's settings; only needed without --db

    return Settings.load(config).database_path


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
        typer.echo(text, nl=False)
        return
    try:
        out.write_text(text, encoding="utf-8")
    except OSError as exc:
        raise _fail(f"cannot write {out}: {exc.strerror}", EXIT_DB_ERROR) from None
    n = found["n_included"] if fmt is ExportFormat.csv else found["n_samples"]
    err_console.print(
        escape(f"wrote {out}: campaign {found['id']} ({found['name']}), {n} samples"),
        soft_wrap=True,
    )


def register(app: typer.Typer) -> None:
    """Add the ``db`` command group to ``app``."""
    app.add_typer(db_app, name="db")
