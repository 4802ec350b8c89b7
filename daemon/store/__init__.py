"""The daemon's SQLite store (via sqlite-utils): robots, campaigns, samples, jobs, results, events.

:class:`Store` is the one object callers use (the sampler's capture sink, the routes, the job
manager, ``cablecal db``). It is assembled from one module per concern:

- :mod:`.db`: the connection, its pragmas (WAL, ``synchronous=FULL``), the one writer
  (a re-entrant lock and ``BEGIN IMMEDIATE``), the read-only open; the durability guarantees
  are stated there.
- :mod:`.schema`: the migrations and the schema version.
- :mod:`.robots`, :mod:`.campaigns`: robots and campaigns (and which has auto capture on).
- :mod:`.samples`: samples: capture ingestion, bulk import, queries.
- :mod:`.export`: a campaign as CSV or JSON.
- :mod:`.jobs`: jobs, results, the calibrated model.
- :mod:`.events`: the event log.
- :mod:`.plans`: pose plans of campaigns.
- :mod:`.checks`: hold checks and check poses.
- :mod:`.rows`: the typed rows every method returns; :mod:`.errors`: the exceptions.

Values returned
    Plain dicts of JSON-friendly values, typed by :mod:`.rows`. Booleans (``excluded``,
    ``auto_capture``, ``interrupted``, ``accepted``) are ``bool``; JSON columns are decoded
    and lose their ``_json`` suffix (``model``, ``options``, ``result``, ``detail``). JSON
    columns are stored as strict JSON: a NaN or infinite float (e.g. the test metrics of a run
    with ``test_fraction=0``) is stored and returned as None.

Not found
    ``robot(id)``, ``campaign(id)``, ``sample(id)``, ``job(id)`` and ``calibrated_model(id)``
    raise :class:`StoreNotFound` (the service answers 404); ``get_robot(id)`` … return None.

Units and time
    Joint angles and their standard deviations in degrees (``q1..q6``, ``q1_std..q6_std``),
    lengths in millimetres (``length_mm``, ``length_std_mm``). Every timestamp
    (``t_start``, ``t_end``, ``t_wall``, ``created_at``, ``started_at``, ``finished_at``) is
    wall-clock time in seconds since the Unix epoch (UTC), stored as REAL. Imported samples
    have no std, count or timestamps (NULL / None).
"""

from __future__ import annotations

from daemon.store.checks import CheckPoses, CheckRow, CheckStore
from daemon.store.db import BUSY_TIMEOUT_MS, DB_FILENAME, Row
from daemon.store.errors import StoreConflict, StoreError, StoreInvalid, StoreNotFound
from daemon.store.events import EventStore
from daemon.store.export import EXPORT_FORMAT, EXPORT_FORMAT_VERSION, ExportStore
from daemon.store.jobs import (
    INTERRUPTED_ERROR,
    JOB_STATUSES,
    JOB_TERMINAL,
    NO_CALIBRATION,
    JobStore,
)
from daemon.store.plans import PlanRow, PlanStore
from daemon.store.rows import (
    JOB_FINISHED,
    CalibratedModel,
    CampaignExport,
    CampaignRow,
    EventRow,
    ExportedSample,
    JobProgress,
    JobRow,
    JobState,
    RawReading,
    ResultRow,
    RobotRow,
    SampleRow,
)
from daemon.store.schema import (
    MIGRATIONS,
    SCHEMA_VERSION,
    Migration,
    apply_migrations,
    schema_version_of,
)


class Store(ExportStore, JobStore, EventStore, PlanStore, CheckStore):
    """The SQLite store. Implements :class:`daemon.sampler.capture.CaptureSink`.

    ``Store(path)`` opens the file, creating or migrating it; ``Store(path, readonly=True)``
    opens an existing file at the current schema version without writing (``cablecal db
    export`` next to a running daemon). Parameters and errors: :class:`~daemon.store.db.StoreDB`.

    The methods live in :class:`~daemon.store.robots.RobotStore`,
    :class:`~daemon.store.campaigns.CampaignStore`, :class:`~daemon.store.samples.SampleStore`,
    :class:`~daemon.store.export.ExportStore`, :class:`~daemon.store.jobs.JobStore`,
    :class:`~daemon.store.events.EventStore`, :class:`~daemon.store.plans.PlanStore` and
    :class:`~daemon.store.checks.CheckStore`, all
    on the one connection of :class:`~daemon.store.db.StoreDB`.
    """


__all__ = [
    "BUSY_TIMEOUT_MS",
    "DB_FILENAME",
    "EXPORT_FORMAT",
    "EXPORT_FORMAT_VERSION",
    "INTERRUPTED_ERROR",
    "JOB_FINISHED",
    "JOB_STATUSES",
    "JOB_TERMINAL",
    "MIGRATIONS",
    "NO_CALIBRATION",
    "SCHEMA_VERSION",
    "CalibratedModel",
    "CampaignExport",
    "CampaignRow",
    "CheckPoses",
    "CheckRow",
    "EventRow",
    "ExportedSample",
    "JobProgress",
    "JobRow",
    "JobState",
    "Migration",
    "PlanRow",
    "PlanStore",
    "RawReading",
    "ResultRow",
    "RobotRow",
    "Row",
    "SampleRow",
    "Store",
    "StoreConflict",
    "StoreError",
    "StoreInvalid",
    "StoreNotFound",
    "apply_migrations",
    "schema_version_of",
]
