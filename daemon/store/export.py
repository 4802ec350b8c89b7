"""Export of a campaign: its included samples as CSV, or everything as JSON."""

from __future__ import annotations

from typing import Final, cast

from calib.dataset import samples_to_csv
from daemon.store.db import now
from daemon.store.rows import CampaignExport, ExportedSample
from daemon.store.samples import SampleStore

EXPORT_FORMAT: Final = "cablecal-campaign"
EXPORT_FORMAT_VERSION: Final = 1


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
