"""The daemon's SQLite store (via sqlite-utils): robots, campaigns, samples, jobs, results, events.

One file under the state directory (:meth:`Store.default_path`), in WAL mode with
``synchronous=FULL``: a write method returns only after its transaction is committed and
the WAL is synced, so an acknowledged capture survives SIGKILL and power loss.

One writer
    A :class:`Store` owns a single connection (``check_same_thread=False``); every method
    takes one re-entrant lock, so calls from the event loop and from a thread pool are
    serialised. Multi-row writes run in one ``BEGIN IMMEDIATE`` transaction (sqlite-utils 4
    nests its own ``atomic()`` blocks inside it as savepoints): all or nothing.

Schema version
    Table ``schema_version`` holds one row per applied migration. :data:`MIGRATIONS` is the
    ordered list; opening an older file applies the missing ones in one transaction, opening a
    file written by a newer cablecal raises :class:`StoreError`.

Values returned
    Plain dicts of JSON-friendly values. Booleans (``excluded``, ``auto_capture``,
    ``interrupted``, ``accepted``) are ``bool``; JSON columns are decoded and lose their
    ``_json`` suffix (``model``, ``options``, ``result``, ``detail``). JSON columns are stored
    as strict JSON: a NaN or infinite float (e.g. the test metrics of a run with
    ``test_fraction=0``) is stored and returned as None.

Units and time
    Joint angles and their standard deviations in degrees (``q1..q6``, ``q1_std..q6_std``),
    lengths in millimetres (``length_mm``, ``length_std_mm``). Every timestamp
    (``t_start``, ``t_end``, ``t_wall``, ``created_at``, ``started_at``, ``finished_at``) is
    wall-clock time in seconds since the Unix epoch (UTC), stored as REAL. Imported samples
    have no std, count or timestamps (NULL / None).
"""

from __future__ import annotations

import json
import math
import sqlite3
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final, Literal

import numpy as np
from sqlite_utils import Database
from sqlite_utils.db import Table

from calib.dataset import (
    JOINT_COLUMNS,
    SampleSet,
    parse_samples_csv,
    samples_to_csv,
    validate_joint_limits,
    validate_values,
)
from calib.kinematics import N_JOINTS, FloatArray
from calib.models import RobotModel, builtin_model, model_from_mapping
from daemon.capture import Capture

if not hasattr(Database, "atomic"):  # pragma: no cover - depends on the installed version
    # sqlite-utils 3.x commits inside every write method (``with conn:``), which would split
    # the store's transactions; 4.x nests its writes in an open transaction as savepoints.
    raise ImportError("daemon.store needs sqlite-utils >= 4 (Database.atomic)")

Row = dict[str, Any]

DB_FILENAME: Final = "cablecal.sqlite3"
BUSY_TIMEOUT_MS: Final = 5000
JOB_STATUSES: Final = ("queued", "running", "succeeded", "failed", "cancelled")
JOB_TERMINAL: Final = ("succeeded", "failed", "cancelled")
INTERRUPTED_ERROR: Final = "interrupted by daemon restart"
EXPORT_FORMAT: Final = "cablecal-campaign"
EXPORT_FORMAT_VERSION: Final = 1

JobStatus = Literal["queued", "running", "succeeded", "failed", "cancelled"]

_Q = JOINT_COLUMNS  # ("q1", ..., "q6")
_Q_STD = tuple(f"{q}_std" for q in JOINT_COLUMNS)
_BOOL_COLUMNS = ("excluded", "auto_capture", "interrupted", "accepted")
_JSON_COLUMNS = ("model_json", "options_json", "result_json", "detail_json")
_JOB_FIELDS = frozenset(
    {"status", "progress", "message", "error", "started_at", "finished_at", "interrupted",
     "options"}
)  # fmt: skip


# ------------------------------------------------------------------------------- errors
class StoreError(Exception):
    """The store cannot do what was asked (database unusable, newer schema, conflict)."""


class StoreNotFound(StoreError, KeyError):
    """A campaign, sample, job, result or robot does not exist.

    Attributes
    ----------
    kind : str
        ``"campaign"``, ``"sample"``, ``"job"``, ``"result"`` or ``"robot"``.
    id : int or str
    """

    def __init__(self, kind: str, id: int | str) -> None:
        super().__init__(f"{kind} {id} not found")
        self.kind = kind
        self.id = id

    def __str__(self) -> str:  # KeyError would show the repr
        return str(self.args[0])


class StoreInvalid(StoreError, ValueError):
    """An argument is invalid (names it); nothing was written."""


# ---------------------------------------------------------------------------- migrations
@dataclass(frozen=True)
class Migration:
    """One schema step; ``apply`` runs inside the migration transaction."""

    version: int
    description: str
    apply: Callable[[sqlite3.Connection], None]


def _joint_columns(suffix: str, constraint: str) -> str:
    return ", ".join(f"{q}{suffix} REAL {constraint}".rstrip() for q in _Q)


def _migration_1(conn: sqlite3.Connection) -> None:
    statements = [
        """CREATE TABLE robots (
            id INTEGER PRIMARY KEY,
            name TEXT NOT NULL CHECK (name <> ''),
            convention TEXT NOT NULL CHECK (convention IN ('dh', 'mdh')),
            model_json TEXT NOT NULL,
            source TEXT NOT NULL CHECK (source IN ('builtin', 'uploaded')),
            created_at REAL NOT NULL
        )""",
        "CREATE UNIQUE INDEX robots_builtin_name ON robots(name) WHERE source = 'builtin'",
        """CREATE TABLE campaigns (
            id INTEGER PRIMARY KEY,
            name TEXT NOT NULL CHECK (name <> ''),
            robot_id INTEGER NOT NULL REFERENCES robots(id),
            notes TEXT NOT NULL DEFAULT '',
            auto_capture INTEGER NOT NULL DEFAULT 0 CHECK (auto_capture IN (0, 1)),
            auto_anchor TEXT NOT NULL DEFAULT 'A' CHECK (auto_anchor <> ''),
            created_at REAL NOT NULL
        )""",
        "CREATE INDEX campaigns_robot_id ON campaigns(robot_id)",
        f"""CREATE TABLE samples (
            id INTEGER PRIMARY KEY,
            campaign_id INTEGER NOT NULL REFERENCES campaigns(id),
            {_joint_columns("", "NOT NULL")},
            length_mm REAL NOT NULL,
            anchor TEXT NOT NULL CHECK (anchor <> ''),
            {_joint_columns("_std", "")},
            length_std_mm REAL,
            count INTEGER CHECK (count IS NULL OR count >= 1),
            t_start REAL,
            t_end REAL,
            mode TEXT CHECK (mode IS NULL OR mode IN ('manual', 'auto')),
            excluded INTEGER NOT NULL DEFAULT 0 CHECK (excluded IN (0, 1)),
            excluded_reason TEXT,
            source TEXT NOT NULL CHECK (source IN ('capture', 'import')),
            created_at REAL NOT NULL
        )""",
        "CREATE INDEX samples_campaign_id ON samples(campaign_id)",
        f"""CREATE TABLE raw_readings (
            id INTEGER PRIMARY KEY,
            sample_id INTEGER NOT NULL REFERENCES samples(id),
            t_wall REAL NOT NULL,
            {_joint_columns("", "NOT NULL")},
            length_mm REAL NOT NULL
        )""",
        "CREATE INDEX raw_readings_sample_id ON raw_readings(sample_id)",
    ]
    for sql in statements:
        conn.execute(sql)


def _migration_2(conn: sqlite3.Connection) -> None:
    statements = [
        # The CSV ``group`` column (pose group for grouped hold-out), kept through import/export.
        "ALTER TABLE samples ADD COLUMN pose_group TEXT",
        """CREATE TABLE jobs (
            id INTEGER PRIMARY KEY,
            campaign_id INTEGER NOT NULL REFERENCES campaigns(id),
            robot_id INTEGER NOT NULL REFERENCES robots(id),
            method TEXT NOT NULL CHECK (method <> ''),
            options_json TEXT NOT NULL DEFAULT '{}',
            status TEXT NOT NULL DEFAULT 'queued'
                CHECK (status IN ('queued', 'running', 'succeeded', 'failed', 'cancelled')),
            progress REAL NOT NULL DEFAULT 0 CHECK (progress >= 0 AND progress <= 1),
            message TEXT NOT NULL DEFAULT '',
            error TEXT,
            created_at REAL NOT NULL,
            started_at REAL,
            finished_at REAL,
            interrupted INTEGER NOT NULL DEFAULT 0 CHECK (interrupted IN (0, 1))
        )""",
        "CREATE INDEX jobs_campaign_id ON jobs(campaign_id)",
        "CREATE INDEX jobs_robot_id ON jobs(robot_id)",
        "CREATE INDEX jobs_status ON jobs(status)",
        """CREATE TABLE results (
            id INTEGER PRIMARY KEY,
            job_id INTEGER NOT NULL UNIQUE REFERENCES jobs(id),
            campaign_id INTEGER NOT NULL REFERENCES campaigns(id),
            robot_id INTEGER NOT NULL REFERENCES robots(id),
            result_json TEXT NOT NULL,
            accepted INTEGER NOT NULL DEFAULT 1 CHECK (accepted IN (0, 1)),
            created_at REAL NOT NULL
        )""",
        "CREATE INDEX results_campaign_id ON results(campaign_id)",
        "CREATE INDEX results_robot_id ON results(robot_id)",
        # events.campaign_id is deliberately not a REFERENCES constraint: the event log must
        # accept a record even when it names a campaign that does not (or no longer) exist.
        """CREATE TABLE events (
            id INTEGER PRIMARY KEY,
            t_wall REAL NOT NULL,
            kind TEXT NOT NULL CHECK (kind <> ''),
            device TEXT,
            campaign_id INTEGER,
            message TEXT NOT NULL DEFAULT '',
            detail_json TEXT
        )""",
        "CREATE INDEX events_kind ON events(kind)",
        "CREATE INDEX events_campaign_id ON events(campaign_id)",
    ]
    for sql in statements:
        conn.execute(sql)


#: The schema history, oldest first; ``version`` is the position (1-based).
MIGRATIONS: Final[tuple[Migration, ...]] = (
    Migration(1, "robots, campaigns, samples, raw_readings", _migration_1),
    Migration(2, "jobs, results, events; samples.pose_group", _migration_2),
)
SCHEMA_VERSION: Final = MIGRATIONS[-1].version


def _table_names(conn: sqlite3.Connection) -> set[str]:
    rows = conn.execute("SELECT name FROM sqlite_master WHERE type = 'table'").fetchall()
    return {str(r[0]) for r in rows}


def schema_version_of(conn: sqlite3.Connection) -> int:
    """The schema version of an open database: 0 for an empty file.

    Raises
    ------
    StoreError
        The file has tables but no ``schema_version`` (not a cablecal database).
    """
    tables = _table_names(conn)
    if "schema_version" not in tables:
        if tables:
            raise StoreError(
                f"not a cablecal database: it has tables {sorted(tables)} but no schema_version"
            )
        return 0
    row = conn.execute("SELECT max(version) FROM schema_version").fetchone()
    return int(row[0]) if row and row[0] is not None else 0


def apply_migrations(conn: sqlite3.Connection, upto: int = SCHEMA_VERSION) -> int:
    """Bring the database to version ``upto`` in one transaction; returns the old version.

    The connection must not be inside a transaction. Exposed for tests (``upto=1`` builds
    the oldest schema).

    Raises
    ------
    StoreError
        The file is newer than ``upto`` allows or is not a cablecal database.
    """
    if not 0 <= upto <= SCHEMA_VERSION:
        raise StoreInvalid(f"upto: must be in 0..{SCHEMA_VERSION}, got {upto}")
    conn.execute("BEGIN IMMEDIATE")
    try:
        current = schema_version_of(conn)
        if current > SCHEMA_VERSION:
            raise StoreError(
                f"database schema version {current} is newer than this cablecal supports "
                f"({SCHEMA_VERSION}); upgrade cablecal or use another database file"
            )
        if current < upto:
            conn.execute(
                "CREATE TABLE IF NOT EXISTS schema_version (version INTEGER PRIMARY KEY, "
                "description TEXT NOT NULL, applied_at REAL NOT NULL)"
            )
            for step in MIGRATIONS[current:upto]:
                step.apply(conn)
                conn.execute(
                    "INSERT INTO schema_version (version, description, applied_at) "
                    "VALUES (?, ?, ?)",
                    (step.version, step.description, time.time()),
                )
    except BaseException:
        conn.rollback()
        raise
    conn.commit()
    return current


# ------------------------------------------------------------------------------- helpers
def _now() -> float:
    return time.time()


def _out(row: Row) -> Row:
    """A database row as a JSON-friendly dict (bools, decoded JSON columns)."""
    out: Row = {}
    for key, value in row.items():
        if key in _BOOL_COLUMNS:
            out[key] = bool(value)
        elif key in _JSON_COLUMNS:
            out[key.removesuffix("_json")] = None if value is None else json.loads(value)
        else:
            out[key] = value
    return out


def _last_id(table: Table) -> int:
    """The rowid of the row ``table.insert`` just wrote."""
    if table.last_pk is None:
        raise StoreError(f"insert into {table.name} returned no id")
    return int(table.last_pk)


def _finite(value: float, name: str) -> float:
    out = float(value)
    if not math.isfinite(out):
        raise StoreInvalid(f"{name}: must be finite, got {value!r}")
    return out


def _joints(values: Sequence[float], name: str) -> list[float]:
    if len(values) != N_JOINTS:
        raise StoreInvalid(f"{name}: must have {N_JOINTS} values, got {len(values)}")
    return [_finite(v, f"{name}[{j}]") for j, v in enumerate(values)]


def _anchor(value: str, name: str = "anchor") -> str:
    if not isinstance(value, str) or not value.strip():
        raise StoreInvalid(f"{name}: must be a non-empty string, got {value!r}")
    return value.strip()


def _strict(value: Any) -> Any:
    """``value`` with every non-finite float (NaN, ±inf) replaced by None, recursively."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _strict(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_strict(v) for v in value]
    return value


def _to_json(value: Any, name: str) -> str:
    """Strict JSON text: NaN and ±inf become null (HTTP clients reject bare NaN)."""
    try:
        return json.dumps(_strict(value), allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise StoreInvalid(f"{name}: not JSON-serialisable: {exc}") from exc


# --------------------------------------------------------------------------------- store
class Store:
    """The SQLite store. Implements :class:`daemon.capture.CaptureSink`.

    Parameters
    ----------
    path : str or Path
        Database file; created (with its parent directories) when missing, unless
        ``readonly``.
    readonly : bool
        Open an existing file read-only (``cablecal db export`` next to a running daemon):
        nothing is created or migrated, and the file must be at the current schema version.

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
            conn = sqlite3.connect(
                str(self.path), check_same_thread=False, timeout=BUSY_TIMEOUT_MS / 1000
            )
        self._conn: sqlite3.Connection | None = conn
        try:
            self._setup(conn)
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

    # ------------------------------------------------------------------ plumbing
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

    def _get(self, table: str, row_id: int) -> Row | None:
        with self._lock:
            rows = list(self._table(table).rows_where("id = ?", [row_id], limit=1))
        return rows[0] if rows else None

    def _require(self, table: str, kind: str, row_id: int) -> Row:
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

    def __enter__(self) -> Store:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ robots
    def _robot_row(self, model: RobotModel, source: str) -> Row:
        return {
            "name": model.name,
            "convention": model.convention,
            "model_json": _to_json(model.to_dict(), "model"),
            "source": source,
            "created_at": _now(),
        }

    def ensure_builtin_robot(self, name: str) -> Row:
        """The built-in model ``name`` (:func:`calib.models.builtin_model`), created on first use.

        An existing row is returned unchanged, so campaigns keep the nominal model they were
        captured against even if the built-in definition changes in a later release.

        Raises
        ------
        calib.models.ModelError
            Unknown built-in name.
        """
        model = builtin_model(name)
        with self._write():
            rows = list(
                self._table("robots").rows_where(
                    "name = ? AND source = 'builtin'", [model.name], limit=1
                )
            )
            if rows:
                return _out(rows[0])
            table = self._table("robots").insert(self._robot_row(model, "builtin"))
            return _out(self._require("robots", "robot", _last_id(table)))

    def add_robot(
        self, model: RobotModel, source: Literal["builtin", "uploaded"] = "uploaded"
    ) -> Row:
        """Store a robot model; returns its row (``model`` is :meth:`RobotModel.to_dict`)."""
        if source not in ("builtin", "uploaded"):
            raise StoreInvalid(f"source: must be 'builtin' or 'uploaded', got {source!r}")
        with self._write():
            try:
                table = self._table("robots").insert(self._robot_row(model, source))
            except sqlite3.IntegrityError as exc:
                raise StoreError(f"robot {model.name!r} ({source}): {exc}") from exc
            return _out(self._require("robots", "robot", _last_id(table)))

    def get_robot(self, robot_id: int) -> Row | None:
        """A robot row, or None."""
        row = self._get("robots", robot_id)
        return None if row is None else _out(row)

    def list_robots(self) -> list[Row]:
        """Every robot, by id."""
        return [_out(r) for r in self._query("SELECT * FROM robots ORDER BY id")]

    def robot_model(self, robot_id: int) -> RobotModel:
        """The stored nominal model as a :class:`RobotModel`.

        Raises
        ------
        StoreNotFound
        """
        row = self._require("robots", "robot", robot_id)
        return model_from_mapping(json.loads(row["model_json"]))

    # ------------------------------------------------------------------ campaigns
    _CAMPAIGN_SELECT = """
        SELECT c.*, r.name AS robot_name,
            (SELECT count(*) FROM samples s WHERE s.campaign_id = c.id) AS n_samples,
            (SELECT count(*) FROM samples s WHERE s.campaign_id = c.id AND s.excluded = 1)
                AS n_excluded
        FROM campaigns c JOIN robots r ON r.id = c.robot_id
    """

    @staticmethod
    def _campaign_out(row: Row) -> Row:
        out = _out(row)
        out["n_included"] = out["n_samples"] - out["n_excluded"]
        return out

    def create_campaign(self, name: str, robot_id: int, notes: str = "") -> Row:
        """A new campaign on robot ``robot_id``.

        Raises
        ------
        StoreNotFound
            No such robot.
        StoreInvalid
            Empty name.
        """
        if not isinstance(name, str) or not name.strip():
            raise StoreInvalid(f"name: must be a non-empty string, got {name!r}")
        with self._write():
            self._require("robots", "robot", robot_id)
            table = self._table("campaigns").insert(
                {"name": name.strip(), "robot_id": robot_id, "notes": notes or "",
                 "auto_capture": False, "auto_anchor": "A", "created_at": _now()}
            )  # fmt: skip
            return self._campaign(_last_id(table))

    def _campaign(self, campaign_id: int) -> Row:
        row = self._one(self._CAMPAIGN_SELECT + " WHERE c.id = ?", [campaign_id])
        if row is None:
            raise StoreNotFound("campaign", campaign_id)
        return self._campaign_out(row)

    def get_campaign(self, campaign_id: int) -> Row | None:
        """A campaign with its robot name and sample counts (``n_samples``, ``n_included``,
        ``n_excluded``), or None."""
        try:
            return self._campaign(campaign_id)
        except StoreNotFound:
            return None

    def list_campaigns(self) -> list[Row]:
        """Every campaign, by id, with sample counts (see :meth:`get_campaign`)."""
        rows = self._query(self._CAMPAIGN_SELECT + " ORDER BY c.id")
        return [self._campaign_out(r) for r in rows]

    def find_campaign(self, ref: str) -> Row:
        """A campaign by id (all digits) or by its unique name.

        Raises
        ------
        StoreNotFound
            No match.
        StoreInvalid
            Several campaigns have that name (the message lists their ids).
        """
        ref = ref.strip()
        if ref.isdigit():
            return self._campaign(int(ref))
        rows = self._query(self._CAMPAIGN_SELECT + " WHERE c.name = ? ORDER BY c.id", [ref])
        if not rows:
            raise StoreNotFound("campaign", repr(ref))
        if len(rows) > 1:
            ids = [r["id"] for r in rows]
            raise StoreInvalid(f"campaign: {len(rows)} campaigns are named {ref!r} (ids {ids})")
        return self._campaign_out(rows[0])

    def set_auto_capture(self, campaign_id: int, enabled: bool, anchor: str = "A") -> Row:
        """Switch auto capture on or off; ``anchor`` is the sensor position id to capture with.

        Raises
        ------
        StoreNotFound
        """
        anchor = _anchor(anchor)
        with self._write():
            self._require("campaigns", "campaign", campaign_id)
            self._table("campaigns").update(
                campaign_id, {"auto_capture": bool(enabled), "auto_anchor": anchor}
            )
            return self._campaign(campaign_id)

    def auto_capture_campaigns(self) -> list[Row]:
        """Campaigns with auto capture on (to resume after a restart), by id."""
        rows = self._query(self._CAMPAIGN_SELECT + " WHERE c.auto_capture = 1 ORDER BY c.id")
        return [self._campaign_out(r) for r in rows]

    # ------------------------------------------------------------------ samples
    def store_capture(self, campaign_id: int, capture: Capture) -> Row:
        """Commit a capture: the sample and its raw readings in one transaction.

        Returns
        -------
        dict
            The sample row (see :meth:`get_sample`), committed and synced.

        Raises
        ------
        StoreNotFound
            No such campaign (nothing is stored).
        StoreInvalid
            A non-finite value, a count below 1, an empty anchor or an unknown mode.
        """
        record: Row = {"campaign_id": campaign_id}
        record.update(zip(_Q, _joints(capture.joints_deg, "joints_deg"), strict=True))
        record["length_mm"] = _finite(capture.length_mm, "length_mm")
        record["anchor"] = _anchor(capture.anchor)
        record.update(zip(_Q_STD, _joints(capture.joints_std_deg, "joints_std_deg"), strict=True))
        record["length_std_mm"] = _finite(capture.length_std_mm, "length_std_mm")
        if capture.count < 1:
            raise StoreInvalid(f"count: must be at least 1, got {capture.count}")
        if capture.mode not in ("manual", "auto"):
            raise StoreInvalid(f"mode: must be 'manual' or 'auto', got {capture.mode!r}")
        record.update(
            count=int(capture.count),
            t_start=_finite(capture.t_start_wall, "t_start_wall"),
            t_end=_finite(capture.t_end_wall, "t_end_wall"),
            mode=capture.mode,
            excluded=False,
            excluded_reason=None,
            source="capture",
            pose_group=None,
            created_at=_now(),
        )
        raw: list[Row] = []
        for k, reading in enumerate(capture.raw):
            r: Row = {"t_wall": _finite(reading.t_wall, f"raw[{k}].t_wall")}
            r.update(zip(_Q, _joints(reading.joints_deg, f"raw[{k}].joints_deg"), strict=True))
            r["length_mm"] = _finite(reading.length_mm, f"raw[{k}].length_mm")
            raw.append(r)
        with self._write():
            self._require("campaigns", "campaign", campaign_id)
            sample_id = _last_id(self._table("samples").insert(record))
            if raw:
                for r in raw:
                    r["sample_id"] = sample_id
                self._table("raw_readings").insert_all(raw)
            return self._sample(sample_id)

    def import_samples(self, campaign_id: int, samples: SampleSet) -> list[int]:
        """Store samples (source ``import``) in one transaction: all or nothing.

        Checks first: finite values, lengths within the sensor range, and joint angles within
        the campaign robot's limits.

        Returns
        -------
        list of int
            The new sample ids, in the order of ``samples``.

        Raises
        ------
        StoreNotFound
            No such campaign.
        calib.dataset.SampleError
            Naming the row (``samples.line``) and column; nothing is stored.
        """
        with self._lock:
            campaign = self._require("campaigns", "campaign", campaign_id)
            validate_values(samples)
            validate_joint_limits(samples, self.robot_model(int(campaign["robot_id"])))
            now = _now()
            records: list[Row] = []
            for i in range(len(samples)):
                rec: Row = {"campaign_id": campaign_id}
                rec.update(zip(_Q, (float(v) for v in samples.joints_deg[i]), strict=True))
                group = samples.group[i] if samples.group is not None else None
                rec.update(
                    length_mm=float(samples.length_mm[i]),
                    anchor=_anchor(samples.anchor[i], f"anchor (row {samples.line_of(i)})"),
                    excluded=False,
                    source="import",
                    pose_group=group or None,
                    created_at=now,
                )
                records.append(rec)
            with self._write():
                before = self.conn.execute("SELECT coalesce(max(id), 0) FROM samples").fetchone()
                self._table("samples").insert_all(records)
                rows = self.conn.execute(
                    "SELECT id FROM samples WHERE id > ? ORDER BY id", (int(before[0]),)
                ).fetchall()
                ids = [int(r[0]) for r in rows]
                if len(ids) != len(records):  # cannot happen with one writer; never half-store
                    raise StoreError(f"import stored {len(ids)} rows, expected {len(records)}")
            return ids

    def import_csv(self, campaign_id: int, text: str) -> list[int]:
        """Parse CSV text (:func:`calib.dataset.parse_samples_csv`) and import it.

        Raises
        ------
        StoreNotFound
            No such campaign (checked before the CSV).
        calib.dataset.SampleError
            With ``row`` (file line, header = 1) and ``column``; nothing is stored.
        """
        with self._lock:
            self._require("campaigns", "campaign", campaign_id)
            return self.import_samples(campaign_id, parse_samples_csv(text))

    def _sample(self, sample_id: int) -> Row:
        return _out(self._require("samples", "sample", sample_id))

    def get_sample(self, sample_id: int) -> Row | None:
        """A sample row, or None. Columns: ``id, campaign_id, q1..q6 [deg], length_mm,
        anchor, q1_std..q6_std [deg], length_std_mm, count, t_start, t_end [s epoch], mode,
        excluded, excluded_reason, source, created_at, pose_group``."""
        row = self._get("samples", sample_id)
        return None if row is None else _out(row)

    def list_samples(self, campaign_id: int, include_excluded: bool = True) -> list[Row]:
        """A campaign's samples, by id.

        Raises
        ------
        StoreNotFound
        """
        with self._lock:
            self._require("campaigns", "campaign", campaign_id)
            where = "campaign_id = ?" + ("" if include_excluded else " AND excluded = 0")
            rows = list(self._table("samples").rows_where(where, [campaign_id], order_by="id"))
        return [_out(r) for r in rows]

    def raw_readings(self, sample_id: int) -> list[Row]:
        """The raw readings of a capture, oldest first (``t_wall, q1..q6, length_mm``).

        Raises
        ------
        StoreNotFound
        """
        with self._lock:
            self._require("samples", "sample", sample_id)
            return list(
                self._table("raw_readings").rows_where(
                    "sample_id = ?", [sample_id], order_by="id",
                    select="t_wall, q1, q2, q3, q4, q5, q6, length_mm",
                )
            )  # fmt: skip

    def set_excluded(self, sample_id: int, excluded: bool, reason: str | None = None) -> Row:
        """Exclude a sample from identification (with a reason) or include it again.

        Raises
        ------
        StoreNotFound
        """
        with self._write():
            self._require("samples", "sample", sample_id)
            self._table("samples").update(
                sample_id,
                {"excluded": bool(excluded), "excluded_reason": reason if excluded else None},
            )
            return self._sample(sample_id)

    def sample_set(self, campaign_id: int) -> tuple[SampleSet, list[int]]:
        """The included samples as a :class:`SampleSet`, ordered by id.

        Returns
        -------
        samples : SampleSet
            ``line`` is ``2..n+1``: the line of each sample in :meth:`export_csv`. ``group``
            is set when any sample has a pose group (others get ``""``).
        ids : list of int, length n
            Sample id of each row.

        Raises
        ------
        StoreNotFound
        """
        rows = self.list_samples(campaign_id, include_excluded=False)
        n = len(rows)
        joints = np.array([[r[q] for q in _Q] for r in rows], dtype=float).reshape(n, N_JOINTS)
        groups = [r["pose_group"] for r in rows]
        samples = SampleSet(
            joints_deg=joints,
            length_mm=np.array([r["length_mm"] for r in rows], dtype=float),
            anchor=tuple(str(r["anchor"]) for r in rows),
            group=tuple(g or "" for g in groups) if any(groups) else None,
            line=np.arange(2, n + 2),
        )
        return samples, [int(r["id"]) for r in rows]

    def poses_deg(self, campaign_id: int) -> FloatArray:
        """Joint angles of every sample of the campaign, excluded ones too, by id.

        Returns
        -------
        ndarray, shape (n, 6)
            [deg]. Auto capture compares new poses against these, so that a restart never
            captures a pose twice.

        Raises
        ------
        StoreNotFound
        """
        with self._lock:
            self._require("campaigns", "campaign", campaign_id)
            rows = self.conn.execute(
                "SELECT q1, q2, q3, q4, q5, q6 FROM samples WHERE campaign_id = ? ORDER BY id",
                (campaign_id,),
            ).fetchall()
        return np.array(rows, dtype=float).reshape(len(rows), N_JOINTS)

    def export_csv(self, campaign_id: int) -> str:
        """The included samples as CSV, exactly what ``cablecal identify`` reads
        (:func:`calib.dataset.samples_to_csv`: 6 decimals, ``anchor``, ``group`` if any).

        An empty campaign gives the header only.

        Raises
        ------
        StoreNotFound
        """
        samples, _ = self.sample_set(campaign_id)
        return samples_to_csv(samples)

    def export_json(self, campaign_id: int, include_raw: bool = False) -> Row:
        """The campaign, its robot and every sample (excluded ones flagged).

        Returns
        -------
        dict
            ``format`` (``"cablecal-campaign"``), ``format_version``, ``schema_version``,
            ``exported_at`` [s epoch], ``campaign``, ``robot`` (with the nominal ``model``),
            ``samples`` (rows as :meth:`get_sample`, each with ``raw_readings`` when
            ``include_raw``).

        Raises
        ------
        StoreNotFound
        """
        with self._lock:
            campaign = self._campaign(campaign_id)
            samples = self.list_samples(campaign_id)
            if include_raw:
                for s in samples:
                    s["raw_readings"] = self.raw_readings(int(s["id"]))
            return {
                "format": EXPORT_FORMAT,
                "format_version": EXPORT_FORMAT_VERSION,
                "schema_version": self.schema_version,
                "exported_at": _now(),
                "campaign": campaign,
                "robot": self.get_robot(int(campaign["robot_id"])),
                "samples": samples,
            }

    # ------------------------------------------------------------------ jobs
    def create_job(self, campaign_id: int, robot_id: int, method: str, options: Row) -> Row:
        """A new job, status ``queued``, progress 0.

        Raises
        ------
        StoreNotFound
            No such campaign or robot.
        StoreInvalid
            Empty method, options not JSON-serialisable.
        """
        if not isinstance(method, str) or not method:
            raise StoreInvalid(f"method: must be a non-empty string, got {method!r}")
        options_json = _to_json(dict(options), "options")
        with self._write():
            self._require("campaigns", "campaign", campaign_id)
            self._require("robots", "robot", robot_id)
            table = self._table("jobs").insert(
                {"campaign_id": campaign_id, "robot_id": robot_id, "method": method,
                 "options_json": options_json, "status": "queued", "progress": 0.0,
                 "message": "", "error": None, "created_at": _now(), "started_at": None,
                 "finished_at": None, "interrupted": False}
            )  # fmt: skip
            return self._job(_last_id(table))

    def _job(self, job_id: int) -> Row:
        return _out(self._require("jobs", "job", job_id))

    def update_job(self, job_id: int, **fields: Any) -> Row:
        """Update a job; returns the new row.

        Parameters
        ----------
        job_id : int
        **fields
            Any of ``status``, ``progress`` (0–1), ``message``, ``error``, ``started_at``,
            ``finished_at`` [s epoch], ``interrupted``, ``options`` (dict). Setting
            ``status="running"`` stamps ``started_at`` if it is unset; a terminal status
            (succeeded, failed, cancelled) stamps ``finished_at`` unless given.

        Raises
        ------
        StoreNotFound
        StoreInvalid
            Unknown field, unknown status, progress outside 0–1.
        """
        unknown = sorted(set(fields) - _JOB_FIELDS)
        if unknown:
            raise StoreInvalid(f"{unknown[0]}: unknown job field (known {sorted(_JOB_FIELDS)})")
        updates: Row = {}
        for key, value in fields.items():
            if key == "status" and value not in JOB_STATUSES:
                raise StoreInvalid(f"status: must be one of {JOB_STATUSES}, got {value!r}")
            if key == "progress":
                value = _finite(value, "progress")
                if not 0.0 <= value <= 1.0:
                    raise StoreInvalid(f"progress: must be within 0..1, got {value}")
            if key == "interrupted":
                value = bool(value)
            if key == "options":
                updates["options_json"] = _to_json(dict(value), "options")
                continue
            updates[key] = value
        with self._write():
            job = self._require("jobs", "job", job_id)
            status = updates.get("status")
            if status == "running" and "started_at" not in updates and job["started_at"] is None:
                updates["started_at"] = _now()
            if status in JOB_TERMINAL and "finished_at" not in updates:
                updates["finished_at"] = _now()
            if updates:
                self._table("jobs").update(job_id, updates)
            return self._job(job_id)

    def get_job(self, job_id: int) -> Row | None:
        """A job row (``options`` decoded, ``interrupted`` bool), or None."""
        row = self._get("jobs", job_id)
        return None if row is None else _out(row)

    def list_jobs(self, campaign_id: int | None = None) -> list[Row]:
        """Jobs by id, all or one campaign's."""
        with self._lock:
            if campaign_id is None:
                rows = list(self._table("jobs").rows_where(order_by="id"))
            else:
                rows = list(
                    self._table("jobs").rows_where("campaign_id = ?", [campaign_id], order_by="id")
                )
        return [_out(r) for r in rows]

    def mark_interrupted(self) -> int:
        """Fail every queued or running job (``interrupted``, error
        ``"interrupted by daemon restart"``). Call at start-up; returns how many."""
        with self._write():
            cur = self.conn.execute(
                "UPDATE jobs SET status = 'failed', interrupted = 1, error = ?, "
                "finished_at = ? WHERE status IN ('queued', 'running')",
                (INTERRUPTED_ERROR, _now()),
            )
            return int(cur.rowcount)

    # ------------------------------------------------------------------ results
    def save_result(self, job_id: int, result_json: Row, accepted: bool = True) -> Row:
        """Store a job's result (the :meth:`IdentifyResult.to_json` mapping).

        Non-finite floats in it are stored as null (strict JSON), see the module docstring.

        Raises
        ------
        StoreNotFound
            No such job.
        StoreError
            The job has a result already.
        """
        text = _to_json(result_json, "result_json")
        with self._write():
            job = self._require("jobs", "job", job_id)
            if self._one("SELECT id FROM results WHERE job_id = ?", [job_id]) is not None:
                raise StoreError(f"job {job_id} already has a result")
            table = self._table("results").insert(
                {"job_id": job_id, "campaign_id": job["campaign_id"],
                 "robot_id": job["robot_id"], "result_json": text, "accepted": bool(accepted),
                 "created_at": _now()}
            )  # fmt: skip
            return _out(self._require("results", "result", _last_id(table)))

    def get_result_for_job(self, job_id: int) -> Row | None:
        """The job's result (``result`` decoded, ``accepted`` bool), or None."""
        row = self._one("SELECT * FROM results WHERE job_id = ?", [job_id])
        return None if row is None else _out(row)

    def set_result_accepted(self, result_id: int, accepted: bool) -> Row:
        """Accept or reject a result as its robot's calibrated model.

        Raises
        ------
        StoreNotFound
        """
        with self._write():
            self._require("results", "result", result_id)
            self._table("results").update(result_id, {"accepted": bool(accepted)})
            return _out(self._require("results", "result", result_id))

    def latest_calibrated_model(self, robot_id: int) -> Row | None:
        """The newest accepted result's calibrated model for a robot, or None.

        Returns
        -------
        dict or None
            ``robot_id, robot`` (name), ``convention, dh`` (rows of ``joint, alpha_deg, a_mm,
            d_mm, theta_deg``), ``tool_mm, method, job_id, campaign_id, result_id,
            created_at, metrics`` (the ``after`` figures).

        Raises
        ------
        StoreNotFound
            No such robot.
        """
        with self._lock:
            robot = self._require("robots", "robot", robot_id)
            row = self._one(
                "SELECT * FROM results WHERE robot_id = ? AND accepted = 1 ORDER BY id DESC "
                "LIMIT 1",
                [robot_id],
            )
        if row is None:
            return None
        result = json.loads(row["result_json"])
        return {
            "robot_id": robot_id,
            "robot": robot["name"],
            "convention": result.get("convention", robot["convention"]),
            "dh": result.get("dh"),
            "tool_mm": result.get("tool_mm"),
            "method": result.get("method"),
            "job_id": row["job_id"],
            "campaign_id": row["campaign_id"],
            "result_id": row["id"],
            "created_at": row["created_at"],
            "metrics": (result.get("metrics") or {}).get("after"),
        }

    # ------------------------------------------------------------------ events
    def record_event(
        self,
        kind: str,
        device: str | None,
        message: str,
        detail: dict[str, Any] | None = None,
        *,
        campaign_id: int | None = None,
    ) -> None:
        """Append an event (``device_error``, ``link_down``, ``link_up``, …).

        ``detail`` is stored as JSON; values JSON cannot represent are stored as their
        ``str``, so recording an event never fails on its payload.
        """
        if not kind:
            raise StoreInvalid("kind: must be a non-empty string")
        detail_json = (
            None if detail is None else json.dumps(_strict(detail), default=str, allow_nan=False)
        )
        with self._write():
            self._table("events").insert(
                {"t_wall": _now(), "kind": kind, "device": device, "campaign_id": campaign_id,
                 "message": message, "detail_json": detail_json}
            )  # fmt: skip

    def record_rejection(
        self, campaign_id: int | None, reason: str, detail: str, device: str | None
    ) -> None:
        """Record a refused capture: kind ``capture_rejected``, message ``"reason: detail"``,
        detail ``{"reason", "detail"}``."""
        self.record_event(
            "capture_rejected",
            device,
            f"{reason}: {detail}",
            {"reason": reason, "detail": detail},
            campaign_id=campaign_id,
        )

    def list_events(
        self,
        kind: str | None = None,
        since_id: int | None = None,
        limit: int = 100,
        campaign_id: int | None = None,
    ) -> list[Row]:
        """Events in id order.

        With ``since_id``: the first ``limit`` events after it (to follow the log). Without:
        the newest ``limit`` events. Rows: ``id, t_wall [s epoch], kind, device, campaign_id,
        message, detail``.
        """
        if not 1 <= limit <= 10_000:
            raise StoreInvalid(f"limit: must be within 1..10000, got {limit}")
        where: list[str] = []
        params: list[Any] = []
        if kind is not None:
            where.append("kind = ?")
            params.append(kind)
        if campaign_id is not None:
            where.append("campaign_id = ?")
            params.append(campaign_id)
        if since_id is not None:
            where.append("id > ?")
            params.append(since_id)
        clause = (" WHERE " + " AND ".join(where)) if where else ""
        order = "ASC" if since_id is not None else "DESC"
        rows = self._query(
            f"SELECT * FROM events{clause} ORDER BY id {order} LIMIT ?", [*params, limit]
        )
        if since_id is None:
            rows.reverse()
        return [_out(r) for r in rows]
