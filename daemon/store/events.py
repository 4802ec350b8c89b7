"""The event log: device errors, link drops and recoveries, refused captures, daemon starts.

``events.campaign_id`` is not a foreign key (see :mod:`daemon.store.schema`): recording an
event never fails because of what it names, nor because of its payload.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from typing import Any, cast

from daemon.store.db import StoreDB, decode_row, now, strict
from daemon.store.errors import StoreInvalid
from daemon.store.rows import EventRow


class EventStore(StoreDB):
    """The event log (part of :class:`daemon.store.Store`)."""

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
            None if detail is None else json.dumps(strict(detail), default=str, allow_nan=False)
        )
        with self._write():
            self._table("events").insert(
                {
                    "t_wall": now(),
                    "kind": kind,
                    "device": device,
                    "campaign_id": campaign_id,
                    "message": message,
                    "detail_json": detail_json,
                }
            )

    def record_rejection(
        self,
        campaign_id: int | None,
        reason: str,
        detail: str,
        device: str | None,
        joints_deg: Sequence[float] | None = None,
    ) -> None:
        """Record a refused capture: kind ``capture_rejected``, message ``"reason: detail"``,
        detail ``{"reason", "detail"}`` and, when known, ``joints_deg`` (6 floats [deg]: the
        pose it was refused at, which a plan's progress reads)."""
        info: dict[str, Any] = {"reason": reason, "detail": detail}
        if joints_deg is not None:
            info["joints_deg"] = [float(v) for v in joints_deg]
        self.record_event(
            "capture_rejected", device, f"{reason}: {detail}", info, campaign_id=campaign_id
        )

    def list_events(
        self,
        kind: str | None = None,
        since_id: int | None = None,
        limit: int = 100,
        campaign_id: int | None = None,
    ) -> list[EventRow]:
        """Events in id order.

        With ``since_id``: the first ``limit`` events after it (to follow the log). Without:
        the newest ``limit`` events. Rows: ``id, t_wall [s epoch], kind, device, campaign_id,
        message, detail``.

        Raises
        ------
        StoreInvalid
            ``limit`` outside 1..10000.
        """
        rows = self._page(
            "SELECT * FROM events",
            [("kind = ?", kind), ("campaign_id = ?", campaign_id), ("id > ?", since_id)],
            limit=limit,
            newest=since_id is None,
        )
        return [cast(EventRow, decode_row(r)) for r in rows]
