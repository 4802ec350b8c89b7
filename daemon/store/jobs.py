"""Domain writes and reads of the identification side: jobs, results, the calibrated model.

A job's state lives here so that a restart finds it; :meth:`JobStore.mark_interrupted` fails
the jobs a stopped daemon left queued or running. A result stores the ``result.json`` mapping
as strict JSON (NaN and ±inf as null). A robot has exactly one current calibration,
``robots.current_identification_id``: accepting a result makes it current (and replaces the
previous one); un-accepting the current one falls back to the newest other accepted result.
"""

from __future__ import annotations

from typing import Any, Final, cast

from calib.result import CalibrationResult
from daemon.store.db import Row, StoreDB, decode_row, finite, last_id, now, or_none, to_json
from daemon.store.errors import StoreError, StoreInvalid, StoreNotFound
from daemon.store.rows import JOB_FINISHED, CalibratedModel, JobRow, JobState, ResultRow

JOB_STATUSES: Final = tuple(s.value for s in JobState)
JOB_TERMINAL: Final = tuple(s.value for s in JobState if s in JOB_FINISHED)
INTERRUPTED_ERROR: Final = "interrupted by daemon restart"
#: The reason of :class:`StoreNotFound` when a robot has no accepted result yet.
NO_CALIBRATION: Final = "no accepted calibration yet"

_JOB_FIELDS = frozenset(
    {
        "status",
        "progress",
        "message",
        "error",
        "started_at",
        "finished_at",
        "interrupted",
        "options",
        "iteration",
        "cost_rms_mm",
    }
)
#: The job row with ``current``: whether its result is its robot's current calibration.
_JOB_SELECT = (
    "SELECT jobs.*, coalesce(robots.current_identification_id = jobs.id, 0) AS current "
    "FROM jobs JOIN robots ON robots.id = jobs.robot_id"
)


def _job_row(row: Row) -> JobRow:
    """A decoded job row: the progress columns as one ``progress`` object."""
    out = decode_row(row)
    cost = out.pop("cost_rms_mm", None)
    out["progress"] = {
        "fraction": float(out["progress"]),
        "iteration": out.pop("iteration", None),
        "cost_rms_mm": None if cost is None else float(cost),
    }
    out["current"] = bool(out["current"])
    return cast(JobRow, out)


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
        if (
            key == "iteration"
            and value is not None
            and (isinstance(value, bool) or not isinstance(value, int) or value < 0)
        ):
            raise StoreInvalid(f"iteration: must be a whole number >= 0, got {value!r}")
        if key == "cost_rms_mm" and value is not None:
            value = finite(value, "cost_rms_mm")
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
                {
                    "campaign_id": campaign_id,
                    "robot_id": robot_id,
                    "method": method,
                    "options_json": options_json,
                    "status": JobState.QUEUED.value,
                    "progress": 0.0,
                    "message": "",
                    "error": None,
                    "created_at": now(),
                    "started_at": None,
                    "finished_at": None,
                    "interrupted": False,
                }
            )
            return self.job(last_id(table))

    def job(self, job_id: int) -> JobRow:
        """A job row (``options`` decoded, ``interrupted`` bool).

        Raises
        ------
        StoreNotFound
        """
        self._require("jobs", "job", job_id)
        return _job_row(self._query(f"{_JOB_SELECT} WHERE jobs.id = ?", [job_id])[0])

    def update_job(self, job_id: int, **fields: Any) -> JobRow:
        """Update a job; returns the new row.

        Parameters
        ----------
        job_id : int
        **fields
            Any of ``status``, ``progress`` (0–1), ``iteration`` (int >= 0), ``cost_rms_mm``
            [mm], ``message``, ``error``, ``started_at``, ``finished_at`` [s epoch],
            ``interrupted``, ``options`` (dict). Setting
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
            if (
                status == JobState.RUNNING
                and "started_at" not in updates
                and job["started_at"] is None
            ):
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
            _JOB_SELECT,
            [("jobs.id > ?", after_id), ("jobs.campaign_id = ?", campaign_id)],
            limit=limit,
            id_column="jobs.id",
        )
        return [_job_row(r) for r in rows]

    def mark_interrupted(self) -> int:
        """Fail every queued or running job (``interrupted``, error
        ``"interrupted by daemon restart"``). Call at start-up; returns how many."""
        with self._write():
            cur = self.conn.execute(
                "UPDATE jobs SET status = ?, interrupted = 1, error = ?, "
                "finished_at = ? WHERE status IN (?, ?)",
                (
                    JobState.FAILED.value,
                    INTERRUPTED_ERROR,
                    now(),
                    JobState.QUEUED.value,
                    JobState.RUNNING.value,
                ),
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
                {
                    "job_id": job_id,
                    "campaign_id": job["campaign_id"],
                    "robot_id": job["robot_id"],
                    "result_json": text,
                    "accepted": bool(accepted),
                    "created_at": now(),
                }
            )
            if accepted:
                self._set_current(int(job["robot_id"]), job_id)
            return self._result(last_id(table))

    def _set_current(self, robot_id: int, job_id: int | None) -> None:
        self.conn.execute(
            "UPDATE robots SET current_identification_id = ? WHERE id = ?", (job_id, robot_id)
        )

    def _result(self, result_id: int) -> ResultRow:
        row = decode_row(self._require("results", "result", result_id))
        current = self._one(
            "SELECT id FROM robots WHERE id = ? AND current_identification_id = ?",
            [row["robot_id"], row["job_id"]],
        )
        return cast(ResultRow, {**row, "current": current is not None})

    def current_job_id(self, robot_id: int) -> int | None:
        """The job id of the robot's current calibration, or None.

        Raises
        ------
        StoreNotFound
        """
        robot = self._require("robots", "robot", robot_id)
        value = robot.get("current_identification_id")
        return None if value is None else int(value)

    def get_result_for_job(self, job_id: int) -> ResultRow | None:
        """The job's result (``result`` decoded, ``accepted`` bool), or None."""
        row = self._one("SELECT id FROM results WHERE job_id = ?", [job_id])
        return None if row is None else self._result(int(row["id"]))

    def set_result_accepted(self, result_id: int, accepted: bool) -> ResultRow:
        """Accept a result as its robot's current calibration (replacing the previous one),
        or withdraw it (a withdrawn current one hands over to the newest other accepted
        result, or to none).

        Raises
        ------
        StoreNotFound
        """
        with self._write():
            row = self._require("results", "result", result_id)
            robot_id, job_id = int(row["robot_id"]), int(row["job_id"])
            self._table("results").update(result_id, {"accepted": bool(accepted)})
            if accepted:
                self._set_current(robot_id, job_id)
            elif self.current_job_id(robot_id) == job_id:
                other = self._one(
                    "SELECT job_id FROM results WHERE robot_id = ? AND accepted = 1 "
                    "ORDER BY id DESC LIMIT 1",
                    [robot_id],
                )
                self._set_current(robot_id, None if other is None else int(other["job_id"]))
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
        result = CalibrationResult.from_json(row["result"])
        after = (result.metrics or {}).get("after")
        return {
            "robot_id": robot_id,
            "robot": robot["name"],
            "convention": str(result.convention or robot["convention"]),
            "dh": None if result.dh is None else [r.to_json() for r in result.dh],
            "tool_mm": None if result.tool_mm is None else list(result.tool_mm),
            "method": result.method,
            "job_id": row["job_id"],
            "campaign_id": row["campaign_id"],
            "result_id": row["id"],
            "created_at": row["created_at"],
            "metrics": None if after is None else dict(after),
        }

    def accepted_result(self, robot_id: int) -> ResultRow:
        """The robot's current calibration's result (``result`` decoded: the ``result.json``
        mapping the calibrated model, compensation and hold checks use).

        Raises
        ------
        StoreNotFound
            No such robot, or (reason :data:`NO_CALIBRATION`) no accepted result for it.
        """
        with self._lock:
            job_id = self.current_job_id(robot_id)
            row = None if job_id is None else self.get_result_for_job(job_id)
        if row is None:
            raise StoreNotFound("robot", robot_id, NO_CALIBRATION)
        return row

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
