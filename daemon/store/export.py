"""Export of a campaign: its included samples as CSV (whole, or streamed page by page), or
everything as JSON."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any, Final, cast

import numpy as np

from calib.dataset import JOINT_COLUMNS, SampleSet, samples_to_csv
from daemon.store.db import now
from daemon.store.rows import CampaignExport, ExportedSample
from daemon.store.samples import SampleStore

EXPORT_FORMAT: Final = "cablecal-campaign"
EXPORT_FORMAT_VERSION: Final = 1
#: Rows of one page of a streamed CSV export: about 0.5 MB of text, built in a few ms.
EXPORT_PAGE_ROWS: Final = 5000
_Q_COLUMNS: Final = ", ".join(JOINT_COLUMNS)


class ExportStore(SampleStore):
    """Campaign export (part of :class:`daemon.store.Store`)."""

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

    def export_csv_pages(
        self, campaign_id: int, page_rows: int = EXPORT_PAGE_ROWS
    ) -> Iterator[str]:
        """:meth:`export_csv`'s text in pieces, read from the store ``page_rows`` rows at a
        time, so a large campaign is never held whole (each piece is the one CSV writer's,
        :func:`calib.dataset.samples_to_csv`, of one page; the header once).

        What the header holds (``group``, ``t_s``) and the time origin are decided first over
        the included samples up to the largest id at that moment, in one query; the pages
        then read those ids. A sample captured while the export runs is not in it; one
        excluded meanwhile is left out of its page (the header, taken before, stays).

        The first piece (the header, and the first page) is made when the generator is first
        advanced: :class:`StoreNotFound` then.
        """
        with self._lock:
            self._require("campaigns", "campaign", campaign_id)
            plan = self._one(
                "SELECT COUNT(*) AS n, MAX(id) AS last_id, "
                "SUM(source <> 'capture' OR t_end IS NULL) AS untimed, "
                "MAX(COALESCE(pose_group, '') <> '') AS grouped "
                "FROM samples WHERE campaign_id = ? AND excluded = 0",
                [campaign_id],
            )
            assert plan is not None  # an aggregate has one row
            n, last_id = int(plan["n"]), int(plan["last_id"] or 0)
            first_t = self._first_t_end(campaign_id, last_id, n, plan)
        after_id, header = 0, True
        while after_id < last_id or header:
            rows = self._query(
                f"SELECT id, {_Q_COLUMNS}, length_mm, anchor, pose_group, t_end FROM samples "
                "WHERE campaign_id = ? AND excluded = 0 AND id > ? AND id <= ? "
                "ORDER BY id LIMIT ?",
                [campaign_id, after_id, last_id, page_rows],
            )
            text = samples_to_csv(_page_set(rows, bool(plan["grouped"]), first_t))
            yield text if header else text.split("\n", 1)[1]
            header = False
            if not rows:
                break
            after_id = int(rows[-1]["id"])

    def _first_t_end(self, campaign_id: int, last_id: int, n: int, plan: Any) -> float | None:
        """The time origin of ``t_s`` [s epoch], or None when the export has no ``t_s``: the
        rule of :func:`calib.dataset.capture_times_s` (at least two samples, all captured and
        timed, times never going back), decided in SQL over the export's rows."""
        if n < 2 or int(plan["untimed"] or 0) > 0:
            return None
        back = self._one(
            "SELECT EXISTS (SELECT 1 FROM (SELECT t_end - LAG(t_end) OVER (ORDER BY id) AS d "
            "FROM samples WHERE campaign_id = ? AND excluded = 0 AND id <= ?) WHERE d < 0) "
            "AS back",
            [campaign_id, last_id],
        )
        if back is None or back["back"]:
            return None
        first = self._one(
            "SELECT t_end FROM samples WHERE campaign_id = ? AND excluded = 0 ORDER BY id LIMIT 1",
            [campaign_id],
        )
        return None if first is None else float(first["t_end"])

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


def _page_set(rows: list[Any], grouped: bool, first_t_end: float | None) -> SampleSet:
    """One page of exported rows as the :class:`SampleSet` :func:`samples_to_csv` writes:
    ``group`` when the campaign has any (``""`` for a row without), ``t_s`` [s] since the
    campaign's first sample when it counts (``first_t_end`` [s epoch], else None)."""
    n = len(rows)
    t_end = np.array([r["t_end"] for r in rows], dtype=float)
    return SampleSet(
        joints_deg=np.array([[r[q] for q in JOINT_COLUMNS] for r in rows], dtype=float).reshape(
            n, len(JOINT_COLUMNS)
        ),
        length_mm=np.array([r["length_mm"] for r in rows], dtype=float),
        anchor=tuple(str(r["anchor"]) for r in rows),
        group=tuple(r["pose_group"] or "" for r in rows) if grouped else None,
        line=np.arange(2, n + 2),
        t_s=None if first_t_end is None else t_end - first_t_end,
    )
