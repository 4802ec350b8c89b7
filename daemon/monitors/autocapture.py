"""Auto capture's one owner: the store and the sampler name the same auto campaign.

The store keeps which campaign has auto capture on (it survives a restart); the sampler does
the capturing. :class:`AutoCapture` is the only code that changes either, so "the store says
auto is on for campaign c with anchor a ⇔ the sampler captures for c with anchor a" holds:

- :meth:`AutoCapture.resume`: at start-up, the sampler as the store says;
- :meth:`AutoCapture.switch`: ``PUT /campaigns/{id}/auto-capture``: validated, stored (one
  transaction), then applied to the sampler; if the sampler refuses, the stored change is
  rolled back and the sampler put back as it was;
- :meth:`AutoCapture.move_anchor`: the sensor watch moves auto capture to a new anchor
  session (or back, on undo), in the store and the sampler;
- :meth:`AutoCapture.start_check` and :meth:`AutoCapture.release`: a hold check
  (:mod:`daemon.monitors.holdcheck`) captures its check campaign in auto mode. That one is
  kept out of the store on purpose: a restart fails the running check rather than resuming
  its captures.

The sampler lives on the event loop: :meth:`switch` runs the store's reads and writes in a
worker thread and the sampler's switch on the loop, one switch at a time.
"""

from __future__ import annotations

import asyncio
import logging
from typing import TYPE_CHECKING, Any

from calib.sample_fields import DEFAULT_ANCHOR

if TYPE_CHECKING:
    from calib.kinematics import FloatArray
    from daemon.store import CampaignRow, Store

log = logging.getLogger("cablecal.service")


class SamplerUnavailable(RuntimeError):
    """Auto capture cannot be switched on: no sampler is running."""


class SamplerRefused(RuntimeError):
    """The sampler refused a switch; the stored change was rolled back."""


class AutoCapture:
    """The one owner of auto capture (see the module docstring).

    Parameters
    ----------
    store : Store
    sampler : object or None
        The daemon's sampler (``set_auto``, ``set_auto_anchor``, ``auto_campaign_id``,
        ``auto_anchor``, ``manual_robot``); None: no sampler runs (switching on refuses).
    """

    def __init__(self, store: Store, sampler: Any = None) -> None:
        self.store = store
        self.sampler = sampler
        #: Held by a switch from the store's write to the sampler's, so that parallel switches
        #: end with the database and the sampler naming the same campaign.
        self._lock = asyncio.Lock()

    @property
    def campaign_id(self) -> int | None:
        """The campaign the sampler captures for in auto mode, or None."""
        if self.sampler is None:
            return None
        cid: int | None = getattr(self.sampler, "auto_campaign_id", None)
        return cid

    @property
    def anchor(self) -> str | None:
        """The anchor auto capture uses, or None when it is off."""
        if self.sampler is None:
            return None
        anchor: str | None = getattr(self.sampler, "auto_anchor", None)
        return anchor

    # ------------------------------------------------------------------ start-up
    def resume(self) -> list[int]:
        """The sampler as the store says (after a restart). Returns the resumed campaign ids."""
        resumed: list[int] = []
        if self.sampler is None:
            return resumed
        for campaign in self.store.auto_capture_campaigns():
            cid = int(campaign["id"])
            self.sampler.set_auto(
                cid,
                anchor=str(campaign.get("auto_anchor") or DEFAULT_ANCHOR),
                known_poses_deg=self.store.poses_deg(cid),
            )
            resumed.append(cid)
            log.info("auto capture resumed", extra={"campaign_id": cid})
        return resumed

    # ------------------------------------------------------------------ the operator's switch
    async def switch(self, campaign_id: int, enabled: bool, anchor: str) -> CampaignRow:
        """Switch auto capture on (for this campaign only: any other goes off) or off.

        Returns
        -------
        CampaignRow
            The switched campaign, as stored.

        Raises
        ------
        daemon.store.StoreNotFound
            No such campaign (nothing changes).
        daemon.store.StoreInvalid
            A blank anchor (nothing changes).
        SamplerUnavailable
            Switching on without a running sampler (nothing changes).
        SamplerRefused
            The sampler refused; the store and the sampler are back as they were.
        """
        async with self._lock:
            before, row, known = await asyncio.to_thread(
                self._store_switch, campaign_id, enabled, anchor
            )
            try:
                if enabled:
                    self.sampler.set_auto(campaign_id, anchor=anchor, known_poses_deg=known)
                elif self.campaign_id == campaign_id:
                    self.sampler.set_auto(None)
            except Exception as exc:
                await asyncio.to_thread(self.store.restore_auto_capture, before)
                await self._restore_sampler(before)
                log.exception("auto capture: the sampler refused; rolled back")
                raise SamplerRefused(str(exc)) from exc
        return row

    def _store_switch(
        self, campaign_id: int, enabled: bool, anchor: str
    ) -> tuple[list[CampaignRow], CampaignRow, FloatArray | None]:
        """The stored part of a switch (in a worker thread): the auto campaigns before, the
        switched row, and the campaign's captured poses [deg] when switching on."""
        self.store.campaign(campaign_id)  # not found before anything changes
        if enabled and self.sampler is None:
            raise SamplerUnavailable("not running")
        before = self.store.auto_capture_campaigns()
        row = self.store.set_auto_capture(campaign_id, enabled, anchor)
        known = self.store.poses_deg(campaign_id) if enabled else None
        return before, row, known

    async def _restore_sampler(self, before: list[CampaignRow]) -> None:
        """The sampler as the restored rows say (best effort: logged if it fails again)."""
        if self.sampler is None:
            return
        try:
            if before:
                cid = int(before[0]["id"])
                known = await asyncio.to_thread(self.store.poses_deg, cid)
                self.sampler.set_auto(cid, anchor=before[0]["auto_anchor"], known_poses_deg=known)
            else:
                self.sampler.set_auto(None)
        except Exception:
            log.exception("auto capture: restoring the sampler failed")

    # ------------------------------------------------------------------ the sensor watch
    def move_anchor(self, campaign_id: int, anchor: str, *, from_anchor: str | None = None) -> bool:
        """If auto capture is on for ``campaign_id`` (and, given ``from_anchor``, uses that
        anchor), its next captures go to ``anchor``, in the store and the sampler. Returns
        whether it moved."""
        if self.campaign_id != campaign_id:
            return False
        if from_anchor is not None and self.anchor != from_anchor:
            return False
        self.store.set_auto_capture(campaign_id, True, anchor)
        self.sampler.set_auto_anchor(anchor)
        return True

    # ------------------------------------------------------------------ hold checks
    def start_check(self, campaign_id: int, anchor: str) -> bool:
        """Auto capture for a hold check's campaign, in the sampler only (not stored, on
        purpose: see the module docstring). Nothing happens without a sampler or with the
        manual robot (no joint angles to settle on). Returns whether it started."""
        if self.sampler is None or getattr(self.sampler, "manual_robot", False):
            return False
        self.sampler.set_auto(campaign_id, anchor=anchor)
        return True

    def release(self, campaign_id: int) -> None:
        """Auto capture off in the sampler if it captures for ``campaign_id``."""
        if self.sampler is not None and self.campaign_id == campaign_id:
            self.sampler.set_auto(None)
