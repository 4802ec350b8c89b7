"""Campaigns: create, read, find, and which campaign has auto capture on.

Samples are in :mod:`daemon.store.samples`, export in :mod:`daemon.store.export`.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from typing import cast

from calib.sample_fields import DEFAULT_ANCHOR
from daemon.store.db import Row, decode_row, last_id, now, or_none
from daemon.store.errors import StoreInvalid, StoreNotFound
from daemon.store.robots import RobotStore
from daemon.store.rows import CampaignRow

#: A campaign row. ``anchors``, the sorted distinct anchors of the included samples, is a skip
#: scan of the index ``samples(campaign_id, excluded, anchor)``: one seek per anchor (the
#: next larger one), not a read of every sample, so polling ``GET /campaigns`` stays cheap.
_CAMPAIGN_SELECT = """
    SELECT c.*, r.name AS robot_name, r.model_name AS robot_model_name,
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


def check_anchor(value: str, name: str = "anchor") -> str:
    if not isinstance(value, str) or not value.strip():
        raise StoreInvalid(f"{name}: must be a non-empty string, got {value!r}")
    return value.strip()


def _campaign_out(row: Row) -> CampaignRow:
    out = decode_row(row)
    out["n_included"] = out["n_samples"] - out["n_excluded"]
    out["plan_id"] = out.pop("plan_id")  # in CampaignRow's order
    out["anchors"] = json.loads(out.pop("anchors"))
    return cast(CampaignRow, out)


class CampaignStore(RobotStore):
    """Campaigns and their auto-capture switch (part of :class:`daemon.store.Store`)."""

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
                {
                    "name": name.strip(),
                    "robot_id": robot_id,
                    "notes": notes or "",
                    "auto_capture": False,
                    "auto_anchor": DEFAULT_ANCHOR,
                    "created_at": now(),
                }
            )
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

    def set_auto_capture(
        self, campaign_id: int, enabled: bool, anchor: str = DEFAULT_ANCHOR
    ) -> CampaignRow:
        """Switch auto capture on or off; ``anchor`` is the sensor position id to capture with.
        Switching on switches every other campaign off, in the same transaction (auto capture
        goes to one campaign at a time).

        Raises
        ------
        StoreNotFound
        StoreInvalid
            A blank anchor (nothing is changed).
        """
        anchor = check_anchor(anchor)
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
