"""Domain writes and reads of the identification side: jobs, results, the calibrated model.

A job's state lives here so that a restart finds it; :meth:`JobStore.mark_interrupted` fails
the jobs a stopped daemon left queued or running. A result stores the ``result.json`` mapping
as strict JSON (NaN and ±inf as null); the newest accepted result of a robot is its
calibrated model.
"""

from __future__ import annotations

from typing import Any, Final, cast

from daemon.store.db import Row, StoreDB, decode_row, finite, last_id, now, or_none, to_json
from daemon.store.errors import StoreError, StoreInvalid, StoreNotFound
from daemon.store.rows import CalibratedModel, JobRow, ResultRow

JOB_STATUSES: Final = ("queued", "running", "succeeded", "failed", "cancelled")
JOB_TERMINAL: Final = ("succeeded", "failed", "cancelled")
INTERRUPTED_ERROR: Final = "interrupted by daemon restart"
#: The reason of :class:`StoreNotFound` when a robot has no accepted result yet.
NO_CALIBRATION: Final = "no accepted calibration yet"

_JOB_FIELDS = frozenset(
    {"status", "progress", "message", "error", "started_at", "finished_at", "interrupted",
     "options"}
)  # fmt: skip


def _job_updates(fields: dict[str, Any]) -> Row:
    """The column updates of :meth:`JobStore.update_job`'s fields, every value checked."""
    unknown = sorted(set(fields) - _JOB_FIELDS)
    if unknown:
        raise StoreInvalid(f"{unknown[0]}: unknown job field (known {sorted(_JOB_FIELDS)})")
    updates: Row = {}
    for key, value in fields.items():
        if key == "status" and value not in JOB_STATUSES:
            raise StoreInvalid(f"status: must be one of {JOB_STATUSES}, got {value!r}")
        if key == "progress":
            value = finite(value, "progress")
            if not 0.0 <= value <= 1.0:
                raise StoreInvalid(f"progress: must be within 0..1, got {value}")
        if key == "interrupted":
            value = bool(value)
        if key == "options":
            updates["options_json"] = to_json(dict(value), "options")
            continue
        updates[key] = value
    return updates


class JobStore(StoreDB):
    """Identification jobs and their results (part of :class:`daemon.store.Store`)."""

    # ------------------------------------------------------------------ jobs
    def create_job(
        self, campaign_id: int, robot_id: int, method: str, options: dict[str, Any]
    ) -> JobRow:
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
        options_json = to_json(dict(options), "options")
        with self._write():
            self._require("campaigns", "campaign", campaign_id)
            self._require("robots", "robot", robot_id)
            table = self._table("jobs").insert(
                {"campaign_id": campaign_id, "robot_id": robot_id, "method": method,
                 "options_json": options_json, "status": "queued", "progress": 0.0,
                 "message": "", "error": None, "created_at": now(), "started_at": None,
                 "finished_at": None, "interrupted": False}
            )  # fmt: skip
            return self.job(last_id(table))

    def job(self, job_id: int) -> JobRow:
        """A job row (``options`` decoded, ``interrupted`` bool).

        Raises
        ------
        StoreNotFound
        """
        return cast(JobRow, decode_row(self._require("jobs", "job", job_id)))

    def update_job(self, job_id: int, **fields: Any) -> JobRow:
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
        updates = _job_updates(fields)
        with self._write():
            job = self._require("jobs", "job", job_id)
            status = updates.get("status")
            if status == "running" and "started_at" not in updates and job["started_at"] is None:
                updates["started_at"] = now()
            if status in JOB_TERMINAL and "finished_at" not in updates:
                updates["finished_at"] = now()
            if updates:
                self._table("jobs").update(job_id, updates)
            return self.job(job_id)

    def get_job(self, job_id: int) -> JobRow | None:
        """A job row (see :meth:`job`), or None."""
        return or_none(self.job, job_id)

    def list_jobs(
        self, campaign_id: int | None = None, after_id: int = 0, limit: int | None = None
    ) -> list[JobRow]:
        """Jobs with ``id > after_id`` by id, all or one campaign's, at most ``limit``
        (None: all).

        Raises
        ------
        StoreInvalid
            ``limit`` outside 1..10000.
        """
        rows = self._page(
            "SELECT * FROM jobs", [("id > ?", after_id), ("campaign_id = ?", campaign_id)],
            limit=limit,
        )  # fmt: skip
        return [cast(JobRow, decode_row(r)) for r in rows]

    def mark_interrupted(self) -> int:
        """Fail every queued or running job (``interrupted``, error
        ``"interrupted by daemon restart"``). Call at start-up; returns how many."""
        with self._write():
            cur = self.conn.execute(
                "UPDATE jobs SET status = 'failed', interrupted = 1, error = ?, "
                "finished_at = ? WHERE status IN ('queued', 'running')",
                (INTERRUPTED_ERROR, now()),
            )
            return int(cur.rowcount)

    # ------------------------------------------------------------------ results
    def save_result(
        self, job_id: int, result_json: dict[str, Any], accepted: bool = True
    ) -> ResultRow:
        """Store a job's result (the :meth:`IdentifyResult.to_json` mapping).

        Non-finite floats in it are stored as null (strict JSON).

        Raises
        ------
        StoreNotFound
            No such job.
        StoreError
            The job has a result already.
        """
        text = to_json(result_json, "result_json")
        with self._write():
            job = self._require("jobs", "job", job_id)
            if self._one("SELECT id FROM results WHERE job_id = ?", [job_id]) is not None:
                raise StoreError(f"job {job_id} already has a result")
            table = self._table("results").insert(
                {"job_id": job_id, "campaign_id": job["campaign_id"],
                 "robot_id": job["robot_id"], "result_json": text, "accepted": bool(accepted),
                 "created_at": now()}
            )  # fmt: skip
            return self._result(last_id(table))

    def _result(self, result_id: int) -> ResultRow:
        return cast(ResultRow, decode_row(self._require("results", "result", result_id)))

    def get_result_for_job(self, job_id: int) -> ResultRow | None:
        """The job's result (``result`` decoded, ``accepted`` bool), or None."""
        row = self._one("SELECT * FROM results WHERE job_id = ?", [job_id])
        return None if row is None else cast(ResultRow, decode_row(row))

    def set_result_accepted(self, result_id: int, accepted: bool) -> ResultRow:
        """Accept or reject a result as its robot's calibrated model.

        Raises
        ------
        StoreNotFound
        """
        with self._write():
            self._require("results", "result", result_id)
            self._table("results").update(result_id, {"accepted": bool(accepted)})
            return self._result(result_id)

    def calibrated_model(self, robot_id: int) -> CalibratedModel:
        """The newest accepted result's calibrated model for a robot.

        Returns
        -------
        CalibratedModel
            ``robot_id, robot`` (name), ``convention, dh`` (rows of ``joint, alpha_deg, a_mm,
            d_mm, theta_deg``), ``tool_mm, method, job_id, campaign_id, result_id,
            created_at, metrics`` (the ``after`` figures).

        Raises
        ------
        StoreNotFound
            No such robot, or (reason :data:`NO_CALIBRATION`) no accepted result for it.
        """
        with self._lock:
            robot = self._require("robots", "robot", robot_id)
            row = self.accepted_result(robot_id)
        result = row["result"]
        return {
            "robot_id": robot_id,
            "robot": robot["name"],
            "convention": str(result.get("convention") or robot["convention"]),
            "dh": result.get("dh"),
            "tool_mm": result.get("tool_mm"),
            "method": result.get("method"),
            "job_id": row["job_id"],
            "campaign_id": row["campaign_id"],
            "result_id": row["id"],
            "created_at": row["created_at"],
            "metrics": (result.get("metrics") or {}).get("after"),
        }

    def accepted_result(self, robot_id: int) -> ResultRow:
        """The newest accepted result of a robot (``result`` decoded: the ``result.json``
        mapping the calibrated model, compensation and drift checks use).

        Raises
        ------
        StoreNotFound
            No such robot, or (reason :data:`NO_CALIBRATION`) no accepted result for it.
        """
        with self._lock:
            self._require("robots", "robot", robot_id)
            row = self._one(
                "SELECT * FROM results WHERE robot_id = ? AND accepted = 1 ORDER BY id DESC "
                "LIMIT 1",
                [robot_id],
            )
        if row is None:
            raise StoreNotFound("robot", robot_id, NO_CALIBRATION)
        return cast(ResultRow, decode_row(row))

    def latest_calibrated_model(self, robot_id: int) -> CalibratedModel | None:
        """The newest accepted result's calibrated model (see :meth:`calibrated_model`), or
        None when the robot has none yet.

        Raises
        ------
        StoreNotFound
            No such robot.
        """
        try:
            return self.calibrated_model(robot_id)
        except StoreNotFound as exc:
            if exc.reason != NO_CALIBRATION:
                raise
            return None
