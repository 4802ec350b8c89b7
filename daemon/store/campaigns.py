"""Domain writes and reads of the capture side: campaigns, samples, import, export.

The store does not parse CSV: callers parse it (:func:`calib.dataset.parse_samples_csv`) and
hand :meth:`CampaignStore.import_samples` a :class:`~calib.dataset.SampleSet`, which is checked
against the campaign robot's joint limits before anything is written.
"""

from __future__ import annotations

import json
from collections.abc import Iterator, Sequence
from typing import Any, Final, cast

import numpy as np

from calib.dataset import (
    JOINT_COLUMNS,
    SampleSet,
    samples_to_csv,
    validate_joint_limits,
    validate_values,
)
from calib.kinematics import N_JOINTS, FloatArray
from daemon.capture import Capture
from daemon.store.db import Row, decode_row, finite, last_id, now, or_none
from daemon.store.errors import StoreError, StoreInvalid, StoreNotFound
from daemon.store.robots import RobotStore
from daemon.store.rows import CampaignExport, CampaignRow, ExportedSample, RawReading, SampleRow

EXPORT_FORMAT: Final = "cablecal-campaign"
EXPORT_FORMAT_VERSION: Final = 1

_Q = JOINT_COLUMNS  # ("q1", ..., "q6")
_Q_STD = tuple(f"{q}_std" for q in JOINT_COLUMNS)

#: A campaign row. ``anchors``, the sorted distinct anchors of the included samples, is a skip
#: scan of the index ``samples(campaign_id, excluded, anchor)``: one seek per anchor (the
#: next larger one), not a read of every sample, so polling ``GET /campaigns`` stays cheap.
_CAMPAIGN_SELECT = """
    SELECT c.*, r.name AS robot_name,
        (SELECT count(*) FROM samples s WHERE s.campaign_id = c.id) AS n_samples,
        (SELECT count(*) FROM samples s WHERE s.campaign_id = c.id AND s.excluded = 1)
            AS n_excluded,
        (SELECT max(p.id) FROM plans p WHERE p.campaign_id = c.id) AS plan_id,
        (WITH RECURSIVE an(a) AS (
            SELECT min(s.anchor) FROM samples s WHERE s.campaign_id = c.id AND s.excluded = 0
            UNION ALL
            SELECT (SELECT min(s.anchor) FROM samples s
                    WHERE s.campaign_id = c.id AND s.excluded = 0 AND s.anchor > an.a)
            FROM an WHERE an.a IS NOT NULL)
         SELECT json_group_array(a) FROM an WHERE a IS NOT NULL) AS anchors
    FROM campaigns c JOIN robots r ON r.id = c.robot_id
"""


def _joints(values: Sequence[float], name: str) -> list[float]:
    if len(values) != N_JOINTS:
        raise StoreInvalid(f"{name}: must have {N_JOINTS} values, got {len(values)}")
    return [finite(v, f"{name}[{j}]") for j, v in enumerate(values)]


def _anchor(value: str, name: str = "anchor") -> str:
    if not isinstance(value, str) or not value.strip():
        raise StoreInvalid(f"{name}: must be a non-empty string, got {value!r}")
    return value.strip()


def _pose_deg(row: SampleRow) -> list[float]:
    """The sample's joint angles ``q1..q6`` [deg]."""
    return [row["q1"], row["q2"], row["q3"], row["q4"], row["q5"], row["q6"]]


def _campaign_out(row: Row) -> CampaignRow:
    out = decode_row(row)
    out["n_included"] = out["n_samples"] - out["n_excluded"]
    out["plan_id"] = out.pop("plan_id")  # in CampaignRow's order
    out["anchors"] = json.loads(out.pop("anchors"))
    return cast(CampaignRow, out)


def _capture_record(campaign_id: int, capture: Capture) -> Row:
    """The ``samples`` row of a capture, every value checked."""
    record: Row = {"campaign_id": campaign_id}
    record.update(zip(_Q, _joints(capture.joints_deg, "joints_deg"), strict=True))
    record["length_mm"] = finite(capture.length_mm, "length_mm")
    record["anchor"] = _anchor(capture.anchor)
    record.update(zip(_Q_STD, _joints(capture.joints_std_deg, "joints_std_deg"), strict=True))
    record["length_std_mm"] = finite(capture.length_std_mm, "length_std_mm")
    if capture.count < 1:
        raise StoreInvalid(f"count: must be at least 1, got {capture.count}")
    if capture.mode not in ("manual", "auto"):
        raise StoreInvalid(f"mode: must be 'manual' or 'auto', got {capture.mode!r}")
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
_IMPORT_COLUMNS = ("campaign_id", *_Q, "length_mm", "anchor", "excluded", "source",
                   "pose_group", "created_at")  # fmt: skip
#: Rows per ``executemany`` of an import (all batches run in one transaction).
IMPORT_BATCH_ROWS: Final = 5000


def _import_batches(campaign_id: int, samples: SampleSet) -> Iterator[Iterator[tuple[Any, ...]]]:
    """The ``samples`` rows of an import (source ``import``, no std, count or timestamps), as
    tuples in :data:`_IMPORT_COLUMNS` order, :data:`IMPORT_BATCH_ROWS` at a time. Each batch
    is a generator: its tuples live only until SQLite has bound them."""
    created_at = now()
    anchors = [
        _anchor(a, f"anchor (row {samples.line_of(i)})") for i, a in enumerate(samples.anchor)
    ]
    groups = samples.group
    for start in range(0, len(samples), IMPORT_BATCH_ROWS):
        stop = min(start + IMPORT_BATCH_ROWS, len(samples))
        # Per batch: a whole-array tolist() would hold the GIL for a second at 500k rows.
        q = samples.joints_deg[start:stop].tolist()
        lengths = samples.length_mm[start:stop].tolist()
        yield (
            (campaign_id, *q[i - start], lengths[i - start], anchors[i], 0, "import",
             (groups[i] or None) if groups is not None else None, created_at)
            for i in range(start, stop)
        )  # fmt: skip


class CampaignStore(RobotStore):
    """Campaigns, samples, import and export (part of :class:`daemon.store.Store`)."""

    # ------------------------------------------------------------------ campaigns
    def create_campaign(self, name: str, robot_id: int, notes: str = "") -> CampaignRow:
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
                 "auto_capture": False, "auto_anchor": "A", "created_at": now()}
            )  # fmt: skip
            return self.campaign(last_id(table))

    def campaign(self, campaign_id: int) -> CampaignRow:
        """A campaign with its robot name, sample counts (``n_samples``, ``n_included``,
        ``n_excluded``), the id of its current (newest) plan, ``plan_id`` (None: no plan), and
        the ``anchors`` of its included samples (sorted; empty without any).

        Raises
        ------
        StoreNotFound
        """
        row = self._one(_CAMPAIGN_SELECT + " WHERE c.id = ?", [campaign_id])
        if row is None:
            raise StoreNotFound("campaign", campaign_id)
        return _campaign_out(row)

    def get_campaign(self, campaign_id: int) -> CampaignRow | None:
        """A campaign (see :meth:`campaign`), or None."""
        return or_none(self.campaign, campaign_id)

    def list_campaigns(self, after_id: int = 0, limit: int | None = None) -> list[CampaignRow]:
        """Campaigns with ``id > after_id``, by id, at most ``limit`` (None: all), with sample
        counts (see :meth:`campaign`).

        Raises
        ------
        StoreInvalid
            ``limit`` outside 1..10000.
        """
        rows = self._page(_CAMPAIGN_SELECT, [("c.id > ?", after_id)], limit=limit, id_column="c.id")
        return [_campaign_out(r) for r in rows]

    def find_campaign(self, ref: str) -> CampaignRow:
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
            return self.campaign(int(ref))
        rows = self._query(_CAMPAIGN_SELECT + " WHERE c.name = ? ORDER BY c.id", [ref])
        if not rows:
            raise StoreNotFound("campaign", repr(ref))
        if len(rows) > 1:
            ids = [r["id"] for r in rows]
            raise StoreInvalid(f"campaign: {len(rows)} campaigns are named {ref!r} (ids {ids})")
        return _campaign_out(rows[0])

    def set_auto_capture(self, campaign_id: int, enabled: bool, anchor: str = "A") -> CampaignRow:
        """Switch auto capture on or off; ``anchor`` is the sensor position id to capture with.
        Switching on switches every other campaign off, in the same transaction (auto capture
        goes to one campaign at a time).

        Raises
        ------
        StoreNotFound
        StoreInvalid
            A blank anchor (nothing is changed).
        """
        anchor = _anchor(anchor)
        with self._write():
            self._require("campaigns", "campaign", campaign_id)
            if enabled:
                self.conn.execute(
                    "UPDATE campaigns SET auto_capture = 0 WHERE auto_capture = 1 AND id != ?",
                    (campaign_id,),
                )
            self._table("campaigns").update(
                campaign_id, {"auto_capture": bool(enabled), "auto_anchor": anchor}
            )
            return self.campaign(campaign_id)

    def restore_auto_capture(self, rows: Sequence[CampaignRow]) -> None:
        """Put auto capture back as it was: exactly the campaigns of ``rows`` (an earlier
        :meth:`auto_capture_campaigns`) on, with their anchors; one transaction."""
        with self._write():
            self.conn.execute("UPDATE campaigns SET auto_capture = 0 WHERE auto_capture = 1")
            for row in rows:
                self._table("campaigns").update(
                    int(row["id"]), {"auto_capture": True, "auto_anchor": row["auto_anchor"]}
                )

    def auto_capture_campaigns(self) -> list[CampaignRow]:
        """Campaigns with auto capture on (to resume after a restart), by id."""
        rows = self._query(_CAMPAIGN_SELECT + " WHERE c.auto_capture = 1 ORDER BY c.id")
        return [_campaign_out(r) for r in rows]

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
        filters = [("campaign_id = ?", campaign_id), ("id > ?", after_id),
                   ("excluded = ?", None if include_excluded else 0)]  # fmt: skip
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
                "sample_id = ?", [sample_id], order_by="id",
                select="t_wall, q1, q2, q3, q4, q5, q6, length_mm",
            )  # fmt: skip
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
        anchor = _anchor(anchor)
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
                    raise StoreInvalid(f"sample_ids: not all of {chunk} belong to campaign "
                                       f"{campaign_id}")  # fmt: skip
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
            is set when any sample has a pose group (others get ``""``).
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

    # ------------------------------------------------------------------ export
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

    def export_json(self, campaign_id: int, include_raw: bool = False) -> CampaignExport:
        """The campaign, its robot and every sample (excluded ones flagged).

        Returns
        -------
        CampaignExport
            ``format`` (``"cablecal-campaign"``), ``format_version``, ``schema_version``,
            ``exported_at`` [s epoch], ``campaign``, ``robot`` (with the nominal ``model``),
            ``samples`` (rows as :meth:`get_sample`, each with ``raw_readings`` when
            ``include_raw``).

        Raises
        ------
        StoreNotFound
        """
        with self._lock:
            campaign = self.campaign(campaign_id)
            samples: list[ExportedSample] = [
                cast(ExportedSample, s) for s in self.list_samples(campaign_id)
            ]
            if include_raw:
                for s in samples:
                    s["raw_readings"] = self.raw_readings(int(s["id"]))
            return {
                "format": EXPORT_FORMAT,
                "format_version": EXPORT_FORMAT_VERSION,
                "schema_version": self.schema_version,
                "exported_at": now(),
                "campaign": campaign,
                "robot": self.robot(int(campaign["robot_id"])),
                "samples": samples,
            }
