"""Samples: capture ingestion, bulk import, and queries.

The store does not parse CSV: callers parse it (:func:`calib.dataset.parse_samples_csv`) and
hand :meth:`SampleStore.import_samples` a :class:`~calib.dataset.SampleSet`, which is checked
against the campaign robot's joint limits before anything is written.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from typing import Any, Final, cast

import numpy as np

from calib.dataset import (
    JOINT_COLUMNS,
    SampleSet,
    capture_times_s,
    validate_joint_limits,
    validate_values,
)
from calib.kinematics import N_JOINTS, FloatArray
from daemon.sampler.capture import CAPTURE_MODES, Capture
from daemon.store.campaigns import CampaignStore, check_anchor
from daemon.store.db import Row, decode_row, finite, last_id, now, or_none
from daemon.store.errors import StoreError, StoreInvalid
from daemon.store.rows import RawReading, SampleRow

_Q = JOINT_COLUMNS  # ("q1", ..., "q6")
_Q_STD = tuple(f"{q}_std" for q in JOINT_COLUMNS)


def _joints(values: Sequence[float], name: str) -> list[float]:
    if len(values) != N_JOINTS:
        raise StoreInvalid(f"{name}: must have {N_JOINTS} values, got {len(values)}")
    return [finite(v, f"{name}[{j}]") for j, v in enumerate(values)]


def _pose_deg(row: SampleRow) -> list[float]:
    """The sample's joint angles ``q1..q6`` [deg]."""
    return [row["q1"], row["q2"], row["q3"], row["q4"], row["q5"], row["q6"]]


def _capture_record(campaign_id: int, capture: Capture) -> Row:
    """The ``samples`` row of a capture, every value checked."""
    record: Row = {"campaign_id": campaign_id}
    record.update(zip(_Q, _joints(capture.joints_deg, "joints_deg"), strict=True))
    record["length_mm"] = finite(capture.length_mm, "length_mm")
    record["anchor"] = check_anchor(capture.anchor)
    record.update(zip(_Q_STD, _joints(capture.joints_std_deg, "joints_std_deg"), strict=True))
    record["length_std_mm"] = finite(capture.length_std_mm, "length_std_mm")
    if capture.count < 1:
        raise StoreInvalid(f"count: must be at least 1, got {capture.count}")
    if capture.mode not in CAPTURE_MODES:
        raise StoreInvalid(f"mode: must be one of {CAPTURE_MODES}, got {capture.mode!r}")
    record.update(
        count=int(capture.count),
        t_start=finite(capture.t_start_wall, "t_start_wall"),
        t_end=finite(capture.t_end_wall, "t_end_wall"),
        mode=capture.mode,
        excluded=False,
        excluded_reason=None,
        source="capture",
        pose_group=None,
        created_at=now(),
    )
    return record


def _raw_records(capture: Capture) -> list[Row]:
    """The ``raw_readings`` rows of a capture (without ``sample_id``), every value checked."""
    raw: list[Row] = []
    for k, reading in enumerate(capture.raw):
        r: Row = {"t_wall": finite(reading.t_wall, f"raw[{k}].t_wall")}
        r.update(zip(_Q, _joints(reading.joints_deg, f"raw[{k}].joints_deg"), strict=True))
        r["length_mm"] = finite(reading.length_mm, f"raw[{k}].length_mm")
        raw.append(r)
    return raw


#: Columns of an imported sample, in the order of :func:`_import_batches`' tuples.
_IMPORT_COLUMNS = (
    "campaign_id",
    *_Q,
    "length_mm",
    "anchor",
    "excluded",
    "source",
    "pose_group",
    "created_at",
)
#: Rows per ``executemany`` of an import (all batches run in one transaction).
IMPORT_BATCH_ROWS: Final = 5000


def _import_batches(campaign_id: int, samples: SampleSet) -> Iterator[Iterator[tuple[Any, ...]]]:
    """The ``samples`` rows of an import (source ``import``, no std, count or timestamps), as
    tuples in :data:`_IMPORT_COLUMNS` order, :data:`IMPORT_BATCH_ROWS` at a time. Each batch
    is a generator: its tuples live only until SQLite has bound them."""
    created_at = now()
    anchors = [
        check_anchor(a, f"anchor (row {samples.line_of(i)})") for i, a in enumerate(samples.anchor)
    ]
    groups = samples.group
    for start in range(0, len(samples), IMPORT_BATCH_ROWS):
        stop = min(start + IMPORT_BATCH_ROWS, len(samples))
        # Per batch: a whole-array tolist() would hold the GIL for a second at 500k rows.
        q = samples.joints_deg[start:stop].tolist()
        lengths = samples.length_mm[start:stop].tolist()
        yield (
            (
                campaign_id,
                *q[i - start],
                lengths[i - start],
                anchors[i],
                0,
                "import",
                (groups[i] or None) if groups is not None else None,
                created_at,
            )
            for i in range(start, stop)
        )


class SampleStore(CampaignStore):
    """Samples of campaigns: captures, imports, queries (part of :class:`daemon.store.Store`)."""

    # ------------------------------------------------------------------ samples
    def store_capture(self, campaign_id: int, capture: Capture) -> SampleRow:
        """Commit a capture: the sample and its raw readings in one transaction.

        Returns
        -------
        SampleRow
            The sample row (see :meth:`get_sample`), committed and synced.

        Raises
        ------
        StoreNotFound
            No such campaign (nothing is stored).
        StoreInvalid
            A non-finite value, a count below 1, an empty anchor or an unknown mode.
        """
        record = _capture_record(campaign_id, capture)
        raw = _raw_records(capture)
        with self._write():
            self._require("campaigns", "campaign", campaign_id)
            sample_id = last_id(self._table("samples").insert(record))
            if raw:
                for r in raw:
                    r["sample_id"] = sample_id
                self._table("raw_readings").insert_all(raw)
            return self.sample(sample_id)

    def import_samples(self, campaign_id: int, samples: SampleSet) -> list[int]:
        """Store samples (source ``import``) in one transaction: all or nothing.

        Checks first: finite values, lengths within the sensor range, and joint angles within
        the campaign robot's limits. CSV text is parsed by the caller
        (:func:`calib.dataset.parse_samples_csv`). The checks run without the store's lock;
        the rows are then inserted :data:`IMPORT_BATCH_ROWS` at a time in one ``BEGIN
        IMMEDIATE`` transaction. The service calls this from a worker thread, off the event
        loop.

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
        campaign = self._require("campaigns", "campaign", campaign_id)
        if len(samples) == 0:
            return []
        validate_values(samples)  # checked before the write lock is taken
        validate_joint_limits(samples, self.robot_model(int(campaign["robot_id"])))
        sql = (
            f"INSERT INTO samples ({', '.join(_IMPORT_COLUMNS)}) "
            f"VALUES ({', '.join('?' * len(_IMPORT_COLUMNS))})"
        )
        with self._write():
            self._require("campaigns", "campaign", campaign_id)  # not deleted meanwhile
            before = int(
                self.conn.execute("SELECT coalesce(max(id), 0) FROM samples").fetchone()[0]
            )
            for batch in _import_batches(campaign_id, samples):
                self.conn.executemany(sql, batch)
            # One writer inside one transaction: the new rows have the ids before+1..before+n
            # in insert order. Checked, never assumed (and no 500k-tuple fetch).
            count, low, high = self.conn.execute(
                "SELECT count(*), min(id), max(id) FROM samples WHERE id > ?", (before,)
            ).fetchone()
            n = len(samples)
            if (count, low, high) != (n, before + 1, before + n):  # never half-store
                raise StoreError(f"import stored ids {low}..{high} ({count} rows), expected {n}")
        return list(range(before + 1, before + n + 1))

    def sample(self, sample_id: int) -> SampleRow:
        """A sample row. Columns: ``id, campaign_id, q1..q6 [deg], length_mm, anchor,
        q1_std..q6_std [deg], length_std_mm, count, t_start, t_end [s epoch], mode, excluded,
        excluded_reason, source, created_at, pose_group``.

        Raises
        ------
        StoreNotFound
        """
        return cast(SampleRow, decode_row(self._require("samples", "sample", sample_id)))

    def get_sample(self, sample_id: int) -> SampleRow | None:
        """A sample row (see :meth:`sample`), or None."""
        return or_none(self.sample, sample_id)

    def list_samples(
        self,
        campaign_id: int,
        include_excluded: bool = True,
        after_id: int = 0,
        limit: int | None = None,
    ) -> list[SampleRow]:
        """A campaign's samples with ``id > after_id``, by id, at most ``limit`` (None: all).

        Raises
        ------
        StoreNotFound
        StoreInvalid
            ``limit`` outside 1..10000.
        """
        filters = [
            ("campaign_id = ?", campaign_id),
            ("id > ?", after_id),
            ("excluded = ?", None if include_excluded else 0),
        ]
        with self._lock:
            self._require("campaigns", "campaign", campaign_id)
            rows = self._page("SELECT * FROM samples", filters, limit=limit)
        return [cast(SampleRow, decode_row(r)) for r in rows]

    def raw_readings(self, sample_id: int) -> list[RawReading]:
        """The raw readings of a capture, oldest first (``t_wall, q1..q6, length_mm``).

        Raises
        ------
        StoreNotFound
        """
        with self._lock:
            self._require("samples", "sample", sample_id)
            rows = self._table("raw_readings").rows_where(
                "sample_id = ?",
                [sample_id],
                order_by="id",
                select="t_wall, q1, q2, q3, q4, q5, q6, length_mm",
            )
            return [cast(RawReading, r) for r in rows]

    def set_excluded(self, sample_id: int, excluded: bool, reason: str | None = None) -> SampleRow:
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
            return self.sample(sample_id)

    def move_samples_to_anchor(
        self, campaign_id: int, sample_ids: Sequence[int], anchor: str
    ) -> int:
        """Put samples of a campaign in another anchor session (the sensor moved, or the
        operator undoes that); one transaction. Returns the number of rows changed.

        Raises
        ------
        StoreNotFound
            No such campaign.
        StoreInvalid
            A blank anchor, or a sample id not of this campaign (nothing is changed).
        """
        anchor = check_anchor(anchor)
        ids = [int(i) for i in sample_ids]
        with self._write():
            self._require("campaigns", "campaign", campaign_id)
            for start in range(0, len(ids), 500):
                chunk = ids[start : start + 500]
                marks = ", ".join("?" * len(chunk))
                found = self.conn.execute(
                    f"SELECT count(*) FROM samples WHERE campaign_id = ? AND id IN ({marks})",
                    (campaign_id, *chunk),
                ).fetchone()[0]
                if found != len(set(chunk)):
                    raise StoreInvalid(
                        f"sample_ids: not all of {chunk} belong to campaign {campaign_id}"
                    )
                self.conn.execute(
                    f"UPDATE samples SET anchor = ? WHERE campaign_id = ? AND id IN ({marks})",
                    (anchor, campaign_id, *chunk),
                )
        return len(set(ids))

    def sample_set(self, campaign_id: int) -> tuple[SampleSet, list[int]]:
        """The included samples as a :class:`SampleSet`, ordered by id.

        Returns
        -------
        samples : SampleSet
            ``line`` is ``2..n+1``: the line of each sample in :meth:`export_csv`. ``group``
            is set when any sample has a pose group (others get ``""``). ``t_s`` is the
            capture time (the end of each capture, [s] since the first) when every sample was
            captured (none imported), else None (the row order is the time).
        ids : list of int, length n
            Sample id of each row.

        Raises
        ------
        StoreNotFound
        """
        rows = self.list_samples(campaign_id, include_excluded=False)
        n = len(rows)
        joints = np.array([_pose_deg(r) for r in rows], dtype=float).reshape(n, N_JOINTS)
        groups = [r["pose_group"] for r in rows]
        # Capture time for the drift model (calib.drift); calib's dataset says when it counts.
        t_s = capture_times_s([r["t_end"] for r in rows], [r["source"] == "capture" for r in rows])
        samples = SampleSet(
            joints_deg=joints,
            length_mm=np.array([r["length_mm"] for r in rows], dtype=float),
            anchor=tuple(str(r["anchor"]) for r in rows),
            group=tuple(g or "" for g in groups) if any(groups) else None,
            line=np.arange(2, n + 2),
            t_s=t_s,
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
