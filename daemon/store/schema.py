"""The store's schema: the ordered migrations and the code that applies them.

Table ``schema_version`` holds one row per applied migration. :data:`MIGRATIONS` is the
ordered list; opening an older file applies the missing ones in one transaction, opening a
file written by a newer cablecal raises :class:`~daemon.store.errors.StoreError`.
"""

from __future__ import annotations

import sqlite3
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Final

from calib.dataset import JOINT_COLUMNS
from calib.sample_fields import DEFAULT_ANCHOR
from daemon.sampler.capture import CAPTURE_MODES
from daemon.store.errors import StoreError, StoreInvalid
from daemon.store.rows import CHECK_STATUSES, CHECK_TRIGGERS, JobState


@dataclass(frozen=True)
class Migration:
    """One schema step; ``apply`` runs inside the migration transaction."""

    version: int
    description: str
    apply: Callable[[sqlite3.Connection], None]


def _one_of(values: tuple[str, ...] | list[str]) -> str:
    """The SQL list of a CHECK (column IN (...)): ``'a', 'b'``. The values are the project's
    own identifiers (states, modes), never user text."""
    return ", ".join(f"'{v}'" for v in values)


def _joint_columns(suffix: str, constraint: str) -> str:
    return ", ".join(f"{q}{suffix} REAL {constraint}".rstrip() for q in JOINT_COLUMNS)


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
        f"""CREATE TABLE campaigns (
            id INTEGER PRIMARY KEY,
            name TEXT NOT NULL CHECK (name <> ''),
            robot_id INTEGER NOT NULL REFERENCES robots(id),
            notes TEXT NOT NULL DEFAULT '',
            auto_capture INTEGER NOT NULL DEFAULT 0 CHECK (auto_capture IN (0, 1)),
            auto_anchor TEXT NOT NULL DEFAULT '{DEFAULT_ANCHOR}' CHECK (auto_anchor <> ''),
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
            mode TEXT CHECK (mode IS NULL OR mode IN ({_one_of(CAPTURE_MODES)})),
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
        f"""CREATE TABLE jobs (
            id INTEGER PRIMARY KEY,
            campaign_id INTEGER NOT NULL REFERENCES campaigns(id),
            robot_id INTEGER NOT NULL REFERENCES robots(id),
            method TEXT NOT NULL CHECK (method <> ''),
            options_json TEXT NOT NULL DEFAULT '{{}}',
            status TEXT NOT NULL DEFAULT '{JobState.QUEUED.value}'
                CHECK (status IN ({_one_of([s.value for s in JobState])})),
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


def _migration_3(conn: sqlite3.Connection) -> None:
    # Pose plans (daemon.store.plans): options, summary and poses as JSON; the newest per
    # campaign is the current one.
    conn.execute(
        """CREATE TABLE plans (
            id INTEGER PRIMARY KEY,
            campaign_id INTEGER NOT NULL REFERENCES campaigns(id),
            robot_id INTEGER NOT NULL REFERENCES robots(id),
            options_json TEXT NOT NULL,
            summary_json TEXT NOT NULL,
            poses_json TEXT NOT NULL,
            created_at REAL NOT NULL
        )"""
    )
    conn.execute("CREATE INDEX plans_campaign_id ON plans(campaign_id)")


#: A check's states as migration 4 wrote them (the verdict ``not_held`` was ``drift`` until
#: migration 8); the current ones are :data:`daemon.store.rows.CHECK_STATUSES`.
_CHECK_STATUSES_V4: Final = ("running", "ok", "drift", "failed")


def _checks_table(name: str, statuses: tuple[str, ...]) -> str:
    """The ``checks`` table's definition under ``name`` with the CHECK of ``statuses``."""
    return f"""CREATE TABLE {name} (
            id INTEGER PRIMARY KEY,
            robot_id INTEGER NOT NULL REFERENCES robots(id),
            campaign_id INTEGER NOT NULL REFERENCES campaigns(id),
            result_id INTEGER NOT NULL REFERENCES results(id),
            trigger TEXT NOT NULL CHECK (trigger IN ({_one_of(CHECK_TRIGGERS)})),
            status TEXT NOT NULL CHECK (status IN ({_one_of(statuses)})),
            refit_anchor INTEGER NOT NULL CHECK (refit_anchor IN (0, 1)),
            threshold_mm REAL NOT NULL CHECK (threshold_mm > 0),
            rms_mm REAL,
            mae_mm REAL,
            max_mm REAL,
            n INTEGER,
            error TEXT,
            started_at REAL NOT NULL,
            finished_at REAL,
            poses_json TEXT NOT NULL,
            detail_json TEXT
        )"""


def _migration_4(conn: sqlite3.Connection) -> None:
    # Hold checks (daemon.store.checks, daemon.monitors.holdcheck): the check poses of each
    # robot and the history of checks.
    statements = [
        """CREATE TABLE check_poses (
            robot_id INTEGER PRIMARY KEY REFERENCES robots(id),
            poses_json TEXT NOT NULL,
            updated_at REAL NOT NULL
        )""",
        _checks_table("checks", _CHECK_STATUSES_V4),
        "CREATE INDEX checks_robot_id ON checks(robot_id)",
        "CREATE INDEX checks_status ON checks(status)",
    ]
    for sql in statements:
        conn.execute(sql)


def _migration_5(conn: sqlite3.Connection) -> None:
    # A campaign's counts and anchors (daemon.store.campaigns) from the index alone: the
    # excluded count is a range count, the distinct anchors a few seeks (a skip scan), instead
    # of reading every sample row of the campaign on each GET /campaigns.
    conn.execute("CREATE INDEX samples_campaign_anchor ON samples(campaign_id, excluded, anchor)")


def _migration_6(conn: sqlite3.Connection) -> None:
    # One current calibration per robot (daemon.store.jobs): the job whose result it is,
    # backfilled with the newest accepted result (what "the calibrated model" meant before);
    # a job's numeric progress: the solver's newest iteration and its data RMS [mm].
    statements = [
        "ALTER TABLE robots ADD COLUMN current_identification_id INTEGER REFERENCES jobs(id)",
        """UPDATE robots SET current_identification_id = (
            SELECT job_id FROM results WHERE results.robot_id = robots.id AND accepted = 1
            ORDER BY results.id DESC LIMIT 1)""",
        "ALTER TABLE jobs ADD COLUMN iteration INTEGER CHECK (iteration IS NULL OR iteration >= 0)",
        "ALTER TABLE jobs ADD COLUMN cost_rms_mm REAL",
    ]
    for sql in statements:
        conn.execute(sql)


def _migration_7(conn: sqlite3.Connection) -> None:
    # A robot is a physical robot (issue 32 item 1): ``name`` becomes the robot's own name
    # (cell, serial number), unique over every robot; ``model_name`` the name of its nominal
    # model. Before, ``name`` was the model's name and each uploaded model file made a robot,
    # so several robots may share one name: the oldest keeps it, each later one is named
    # "<name> (robot <id>)", and none is merged (the old store cannot tell whether two rows
    # are one arm). Every campaign, sample, job, result, plan and check keeps its robot id.
    statements = [
        "ALTER TABLE robots ADD COLUMN model_name TEXT NOT NULL DEFAULT ''",
        "UPDATE robots SET model_name = name",
        """UPDATE robots SET name = name || ' (robot ' || id || ')'
            WHERE id > (SELECT min(r.id) FROM robots r WHERE r.name = robots.name)""",
        "DROP INDEX robots_builtin_name",
        "CREATE UNIQUE INDEX robots_name ON robots(name)",
    ]
    for sql in statements:
        conn.execute(sql)


def _migration_8(conn: sqlite3.Connection) -> None:
    # One name per meaning (issue 33 item 2): the check that a robot holds its calibration is
    # the hold check; "drift" is only the measurement's drift (calib.drift). A check's verdict
    # ``drift`` becomes ``not_held`` (the table is rebuilt: SQLite cannot change a CHECK),
    # and the stored events ``drift`` and ``drift_check`` become ``hold_check_not_held`` and
    # ``hold_check`` (their detail's ``status`` too), and a check campaign's notes say
    # "hold check", so old rows read as new ones.
    columns = (
        "id, robot_id, campaign_id, result_id, trigger, status, refit_anchor, threshold_mm, "
        "rms_mm, mae_mm, max_mm, n, error, started_at, finished_at, poses_json, detail_json"
    )
    renamed = columns.replace(
        "status,", "CASE status WHEN 'drift' THEN 'not_held' ELSE status END,"
    )
    statements = [
        _checks_table("checks_v8", CHECK_STATUSES),
        f"INSERT INTO checks_v8 ({columns}) SELECT {renamed} FROM checks",
        "DROP TABLE checks",
        "ALTER TABLE checks_v8 RENAME TO checks",
        "CREATE INDEX checks_robot_id ON checks(robot_id)",
        "CREATE INDEX checks_status ON checks(status)",
        """UPDATE events SET detail_json = json_set(detail_json, '$.status', 'not_held')
            WHERE kind IN ('drift', 'drift_check') AND json_valid(detail_json)
            AND json_extract(detail_json, '$.status') = 'drift'""",
        "UPDATE events SET kind = 'hold_check_not_held' WHERE kind = 'drift'",
        "UPDATE events SET kind = 'hold_check' WHERE kind = 'drift_check'",
        # A check's own campaign is noted "hold check (<trigger>) against result <id>"; the
        # page tells those from the operator's campaigns by that start.
        """UPDATE campaigns SET notes = 'hold check' || substr(notes, 12)
            WHERE notes LIKE 'drift check (%'""",
    ]
    for sql in statements:
        conn.execute(sql)


#: The schema history, oldest first; ``version`` is the position (1-based).
MIGRATIONS: Final[tuple[Migration, ...]] = (
    Migration(1, "robots, campaigns, samples, raw_readings", _migration_1),
    Migration(2, "jobs, results, events; samples.pose_group", _migration_2),
    Migration(3, "plans", _migration_3),
    Migration(4, "hold checks: check_poses, checks", _migration_4),
    Migration(5, "samples index (campaign_id, excluded, anchor)", _migration_5),
    Migration(6, "robots.current_identification_id; jobs progress numbers", _migration_6),
    Migration(
        7, "a robot is a physical robot: robots.name unique, robots.model_name", _migration_7
    ),
    Migration(8, "hold checks: verdict not_held, events hold_check*", _migration_8),
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
