"""Connection plumbing of the store: open, pragmas, the one writer, row decoding.

Durability
    One file under the state directory (:meth:`StoreDB.default_path`), in WAL mode with
    ``synchronous=FULL``: a write method returns only after its transaction is committed and
    the WAL is synced, so an acknowledged capture survives SIGKILL and power loss.

One writer
    A store owns a single connection (``check_same_thread=False``); every method takes one
    re-entrant lock, so calls from the event loop and from a thread pool are serialised.
    Multi-row writes run in one ``BEGIN IMMEDIATE`` transaction (sqlite-utils 4 nests its own
    ``atomic()`` blocks inside it as savepoints): all or nothing.

File modes
    A new database is created 0640 (less the umask); SQLite gives the ``-wal`` and ``-shm``
    files the database's mode, and an older file readable by others loses those bits on the
    next read-write open. Under systemd (``UMask=0027``) the ``cablecal`` group, operators,
    may read it; nobody else may.

Read-only open
    ``readonly=True`` opens an existing file with ``mode=ro`` (``cablecal db export`` next to
    a running daemon): nothing is created or migrated, and the file must be at the current
    schema version.

The domain modules (:mod:`.campaigns`, :mod:`.jobs`, :mod:`.events`) subclass
:class:`StoreDB` and use only its protected helpers (``_write``, ``_query``, ``_require``, …)
and the value helpers below; :class:`daemon.store.Store` combines them.
"""

from __future__ import annotations

import json
import math
import os
import sqlite3
import stat
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Final, Self, TypeVar

from sqlite_utils import Database
from sqlite_utils.db import Table

from daemon.store.errors import StoreError, StoreInvalid, StoreNotFound
from daemon.store.schema import SCHEMA_VERSION, apply_migrations, schema_version_of

if not hasattr(Database, "atomic"):  # pragma: no cover - depends on the installed version
    # sqlite-utils 3.x commits inside every write method (``with conn:``), which would split
    # the store's transactions; 4.x nests its writes in an open transaction as savepoints.
    raise ImportError("daemon.store needs sqlite-utils >= 4 (Database.atomic)")

T = TypeVar("T")

#: A database row as sqlite-utils gives it (column name → value), before :func:`decode_row`.
Row = dict[str, Any]

DB_FILENAME: Final = "cablecal.sqlite3"
BUSY_TIMEOUT_MS: Final = 5000
#: Mode of a new database file (the umask may remove more); never readable by others.
DB_FILE_MODE: Final = 0o640
#: The files SQLite keeps next to the database (WAL mode: -wal, -shm; rollback: -journal).
SIDE_FILE_SUFFIXES: Final = ("-wal", "-shm", "-journal")
#: The most rows one list call may return (``limit``); the REST pages share it.
MAX_PAGE_ROWS: Final = 10_000

_BOOL_COLUMNS = ("excluded", "auto_capture", "interrupted", "accepted")
_JSON_COLUMNS = ("model_json", "options_json", "result_json", "detail_json")


# ------------------------------------------------------------------------------- values
def now() -> float:
    """Wall-clock time [s since the Unix epoch, UTC]: every timestamp the store writes."""
    return time.time()


def decode_row(row: Row) -> Row:
    """A database row as a JSON-friendly dict: the boolean columns as ``bool``, the JSON
    columns decoded and without their ``_json`` suffix."""
    out: Row = {}
    for key, value in row.items():
        if key in _BOOL_COLUMNS:
            out[key] = bool(value)
        elif key in _JSON_COLUMNS:
            out[key.removesuffix("_json")] = None if value is None else json.loads(value)
        else:
            out[key] = value
    return out


def last_id(table: Table) -> int:
    """The rowid of the row ``table.insert`` just wrote."""
    if table.last_pk is None:
        raise StoreError(f"insert into {table.name} returned no id")
    return int(table.last_pk)


def finite(value: float, name: str) -> float:
    """``value`` as a float; :class:`StoreInvalid` naming ``name`` if NaN or infinite."""
    out = float(value)
    if not math.isfinite(out):
        raise StoreInvalid(f"{name}: must be finite, got {value!r}")
    return out


def strict(value: Any) -> Any:
    """``value`` with every non-finite float (NaN, ±inf) replaced by None, recursively."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: strict(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [strict(v) for v in value]
    return value


def to_json(value: Any, name: str) -> str:
    """Strict JSON text: NaN and ±inf become null (HTTP clients reject bare NaN)."""
    try:
        return json.dumps(strict(value), allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise StoreInvalid(f"{name}: not JSON-serialisable: {exc}") from exc


def or_none(lookup: Callable[[int], T], row_id: int) -> T | None:
    """``lookup(row_id)``, or None where it raises :class:`StoreNotFound`: the ``get_*``
    methods are their raising twins (``robot``, ``campaign``, …) made optional."""
    try:
        return lookup(row_id)
    except StoreNotFound:
        return None


def check_limit(limit: int) -> int:
    """``limit`` if it is within 1..:data:`MAX_PAGE_ROWS`; :class:`StoreInvalid` naming
    ``limit`` otherwise."""
    if not 1 <= limit <= MAX_PAGE_ROWS:
        raise StoreInvalid(f"limit: must be within 1..{MAX_PAGE_ROWS}, got {limit}")
    return limit


def where_clause(filters: Sequence[tuple[str, Any]]) -> tuple[str, list[Any]]:
    """A ``WHERE`` clause and its parameters from ``(condition, value)`` pairs.

    Each condition holds one ``?`` for its value; a pair whose value is None is left out (the
    filter was not asked for). Returns ``(" WHERE a = ? AND b > ?", [va, vb])``, or ``("",
    [])`` when no filter applies.
    """
    used = [(cond, value) for cond, value in filters if value is not None]
    if not used:
        return "", []
    return " WHERE " + " AND ".join(c for c, _ in used), [v for _, v in used]


# ----------------------------------------------------------------------------- file modes
def create_private(path: Path) -> bool:
    """Create ``path`` empty with mode 0640 (less what the umask removes) unless it exists;
    returns True if it was created. SQLite gives its ``-wal`` and ``-shm`` files the mode of
    the database file, so none of the three is ever world-readable, whatever the umask."""
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, DB_FILE_MODE)
    except FileExistsError:
        return False
    os.close(fd)
    return True


def restrict_modes(path: Path) -> None:
    """Remove the "others" permission bits from the database and its ``-wal``, ``-shm`` and
    ``-journal`` files (a database from before modes were set); a file we may not chmod (not
    ours) is left as it is."""
    for file in (path, *(path.with_name(path.name + s) for s in SIDE_FILE_SUFFIXES)):
        try:
            mode = stat.S_IMODE(file.stat().st_mode)
            if mode & 0o007:
                os.chmod(file, mode & ~0o007)
        except (FileNotFoundError, PermissionError):
            continue


# --------------------------------------------------------------------------- connection
class StoreDB:
    """One SQLite file: the connection, its pragmas, the lock and the write transaction.

    Parameters
    ----------
    path : str or Path
        Database file; created (with its parent directories) when missing, unless
        ``readonly``.
    readonly : bool
        Open an existing file read-only: nothing is created or migrated, and the file must
        be at the current schema version.

    Raises
    ------
    StoreError
        The file is from a newer cablecal, is not a cablecal database, cannot be opened, or
        (read-only) is missing or older.
    """

    def __init__(self, path: str | Path, *, readonly: bool = False) -> None:
        self.path = Path(path)
        self.readonly = readonly
        self._lock = threading.RLock()
        if readonly:
            if not self.path.is_file():
                raise StoreError(f"{self.path}: no such database file")
            uri = self.path.resolve().as_uri() + "?mode=ro"
            conn = sqlite3.connect(
                uri, uri=True, check_same_thread=False, timeout=BUSY_TIMEOUT_MS / 1000
            )
        else:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            create_private(self.path)
            conn = sqlite3.connect(
                str(self.path), check_same_thread=False, timeout=BUSY_TIMEOUT_MS / 1000
            )
        self._conn: sqlite3.Connection | None = conn
        try:
            self._setup(conn)
            if not readonly:
                restrict_modes(self.path)
        except sqlite3.DatabaseError as exc:
            conn.close()
            self._conn = None
            raise StoreError(f"{self.path}: cannot open the database: {exc}") from exc
        except BaseException:
            conn.close()
            self._conn = None
            raise

    def _setup(self, conn: sqlite3.Connection) -> None:
        conn.execute(f"PRAGMA busy_timeout = {BUSY_TIMEOUT_MS}")
        conn.execute("PRAGMA foreign_keys = ON")
        conn.execute("PRAGMA synchronous = FULL")
        if self.readonly:
            version = schema_version_of(conn)
            if version != SCHEMA_VERSION:
                newer = version > SCHEMA_VERSION
                raise StoreError(
                    f"{self.path}: database schema version {version} is "
                    + (
                        f"newer than this cablecal supports ({SCHEMA_VERSION}); upgrade cablecal"
                        if newer
                        else f"older than {SCHEMA_VERSION}; open it once read-write (start "
                        "the daemon) to migrate it"
                    )
                )
        else:
            mode = conn.execute("PRAGMA journal_mode = WAL").fetchone()[0]
            if str(mode).lower() != "wal":
                raise StoreError(f"{self.path}: cannot enable WAL mode (journal_mode={mode})")
            try:
                apply_migrations(conn)
            except StoreError as exc:
                raise StoreError(f"{self.path}: {exc}") from None
        self.db = Database(conn, execute_plugins=False)

    @staticmethod
    def default_path(state_dir: str | Path) -> Path:
        """``state_dir / "cablecal.sqlite3"``."""
        return Path(state_dir) / DB_FILENAME

    @property
    def conn(self) -> sqlite3.Connection:
        """The connection (raises :class:`StoreError` after :meth:`close`)."""
        if self._conn is None:
            raise StoreError(f"{self.path}: the store is closed")
        return self._conn

    @contextmanager
    def _write(self) -> Iterator[Database]:
        """Lock, then one ``BEGIN IMMEDIATE`` … ``COMMIT`` (nested calls join it)."""
        with self._lock:
            conn = self.conn
            if self.readonly:
                raise StoreError(f"{self.path}: the store is open read-only")
            if conn.in_transaction:
                with self.db.atomic():
                    yield self.db
                return
            conn.execute("BEGIN IMMEDIATE")
            try:
                yield self.db
                conn.commit()
            except BaseException:
                conn.rollback()
                raise

    def _table(self, name: str) -> Table:
        return self.db.table(name)

    def _query(self, sql: str, params: Sequence[Any] = ()) -> list[Row]:
        with self._lock:
            cur = self.conn.execute(sql, tuple(params))
            names = [d[0] for d in cur.description]
            return [dict(zip(names, r, strict=True)) for r in cur.fetchall()]

    def _one(self, sql: str, params: Sequence[Any] = ()) -> Row | None:
        rows = self._query(sql, params)
        return rows[0] if rows else None

    def _page(
        self,
        select: str,
        filters: Sequence[tuple[str, Any]],
        *,
        limit: int | None,
        newest: bool = False,
        id_column: str = "id",
    ) -> list[Row]:
        """Rows of ``select`` (``SELECT … FROM …``, no ``WHERE``) that match ``filters`` (see
        :func:`where_clause`), in ``id_column`` order, at most ``limit`` of them.

        ``newest=False``: the first ``limit`` rows (a page after a cursor); ``newest=True``:
        the last ``limit`` rows, still oldest first. ``limit`` None: every row; otherwise it
        must pass :func:`check_limit`.
        """
        clause, params = where_clause(filters)
        cap = -1 if limit is None else check_limit(limit)
        order = "DESC" if newest else "ASC"
        rows = self._query(f"{select}{clause} ORDER BY {id_column} {order} LIMIT ?", [*params, cap])
        if newest:
            rows.reverse()
        return rows

    def _get(self, table: str, row_id: int) -> Row | None:
        with self._lock:
            rows = list(self._table(table).rows_where("id = ?", [row_id], limit=1))
        return rows[0] if rows else None

    def _require(self, table: str, kind: str, row_id: int) -> Row:
        """The raw row ``row_id`` of ``table``; :class:`StoreNotFound` (``kind``) if none."""
        row = self._get(table, row_id)
        if row is None:
            raise StoreNotFound(kind, row_id)
        return row

    @property
    def schema_version(self) -> int:
        """The schema version of the open file."""
        with self._lock:
            return schema_version_of(self.conn)

    def integrity_check(self) -> str:
        """``PRAGMA integrity_check``: ``"ok"``, or the problems found, one per line."""
        with self._lock:
            rows = self.conn.execute("PRAGMA integrity_check").fetchall()
        return "\n".join(str(r[0]) for r in rows)

    def pragma(self, name: str) -> Any:
        """The value of a read-only pragma (``journal_mode``, ``synchronous``, …)."""
        if not name.replace("_", "").isalpha():
            raise StoreInvalid(f"name: not a pragma name: {name!r}")
        with self._lock:
            row = self.conn.execute(f"PRAGMA {name}").fetchone()
        return None if row is None else row[0]

    def close(self) -> None:
        """Close the connection (idempotent). The WAL is checkpointed by SQLite."""
        with self._lock:
            if self._conn is not None:
                self._conn.close()
                self._conn = None

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
