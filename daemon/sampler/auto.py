"""Auto capture: the state of one campaign in auto mode and the decision taken each poll cycle.

The sampler calls :meth:`AutoState.decide` after each cycle with the settle verdict and any
device fault; the decision is one of: do nothing, record a rejection, or store the settled
window. The sampler carries it out (:meth:`daemon.sampler.Sampler._auto_step`) and reports a
failed store back with :meth:`AutoState.store_failed`.

Rules: the loop captures once at each new settled pose; after a capture (or a refusal) the robot
must move before the next, and a pose within ``auto_new_pose_deg`` (every joint) of a pose
already captured in the campaign is never captured again. A device fault is recorded once per
error episode; a pose that cannot settle (still but over-range, or still for longer than
``capture_timeout_s`` without settling) is recorded once until the robot moves.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from calib.dataset import known_pose_index
from daemon.capture import CaptureRejected, Joints
from daemon.devices import Device
from daemon.sampler.config import SamplerConfig
from daemon.settle import Verdict

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class AutoAction:
    """What the sampler does after an auto step: record ``reject``, or store the window."""

    reject: CaptureRejected | None = None
    store: bool = False


#: Nothing to do this cycle.
NOTHING = AutoAction()


@dataclass
class AutoState:
    """Auto-capture state of one campaign."""

    campaign_id: int
    anchor: str
    known: FloatArray  # shape (n, 6) [deg], poses captured in the campaign
    since: float  # monotonic time auto mode was enabled
    need_motion: bool = False  # captured (or refused) here: wait until the robot moves
    pose_ref: FloatArray | None = None  # where need_motion was set [deg]
    still_since: float | None = None
    pose_recorded: bool = False  # a rejection was recorded at the current pose
    reported_known: set[int] = field(default_factory=set)  # not_new_pose recorded per pose
    fault_keys: set[tuple[str, int]] = field(default_factory=set)  # (device, episode)
    retry_after: float = 0.0  # after a failed store

    def stay(self, joints_deg: FloatArray) -> None:
        """Captured or refused at this pose: the robot must move before the next capture."""
        self.need_motion, self.pose_ref = True, joints_deg

    def saw_joints(self, joints_deg: Joints, tol_deg: float) -> None:
        """A robot reading (paired or not): once the robot left the pose, clear
        ``need_motion`` and ``pose_recorded``."""
        ref = self.pose_ref
        if ref is not None and np.abs(ref - joints_deg).max() > tol_deg:
            self.need_motion = self.pose_recorded = False
            self.pose_ref = None

    def captured(self, pose_deg: FloatArray) -> None:
        """A capture at ``pose_deg`` (shape (6,) [deg]) was stored in this campaign."""
        self.known = np.vstack([self.known, pose_deg[None, :]])
        self.stay(pose_deg)

    def store_failed(self, now: float, cfg: SamplerConfig) -> None:
        """Storing the window failed at monotonic ``now`` [s]: wait before trying again."""
        self.retry_after = now + max(cfg.error_backoff_s, cfg.settle_s)

    def decide(
        self,
        verdict: Verdict,
        fault: tuple[CaptureRejected, Device] | None,
        now: float,
        cfg: SamplerConfig,
        last_joints_deg: Joints | None,
    ) -> AutoAction:
        """The step to take at monotonic ``now`` [s].

        Parameters
        ----------
        verdict : Verdict
            Settle check of the window polled since auto mode was enabled and after the last
            capture.
        fault : (CaptureRejected, Device) or None
            A device failing (or the manual robot without angles) since auto mode was enabled.
        cfg : SamplerConfig
        last_joints_deg : Joints or None
            Joint angles [deg] of the newest paired reading.
        """
        if verdict.joints_still is False:
            self.need_motion = self.pose_recorded = False
            self.still_since = None
        elif verdict.joints_still and self.still_since is None:
            self.still_since = now

        if fault is not None:
            rejection, dev = fault
            key = (dev.role, dev.episode)
            if key in self.fault_keys:
                return NOTHING
            self.fault_keys.add(key)
            return AutoAction(reject=rejection)
        if verdict.reason is None:
            return self._settled(verdict, now, cfg)
        if verdict.joints_still and not self.need_motion and not self.pose_recorded:
            stuck = self.still_since is not None and now - self.still_since > cfg.capture_timeout_s
            if verdict.final or stuck:
                self.pose_recorded = True
                if last_joints_deg is not None:
                    self.pose_ref = np.array(last_joints_deg)
                return AutoAction(reject=CaptureRejected(verdict.reason, verdict.detail))
        return NOTHING

    def _settled(self, verdict: Verdict, now: float, cfg: SamplerConfig) -> AutoAction:
        """A settled window: store it unless the robot has not moved or the pose is known."""
        if self.need_motion or now < self.retry_after:
            return NOTHING
        q = np.array([r.joints_deg for r in verdict.window]).mean(axis=0)
        index = known_pose_index(self.known, q, cfg.auto_new_pose_deg)  # the one repeat rule
        if index is None:
            return AutoAction(store=True)
        self.stay(q)
        if index in self.reported_known:
            return NOTHING
        self.reported_known.add(index)
        detail = f"pose {np.round(q, 3).tolist()} deg was captured already"
        return AutoAction(reject=CaptureRejected("not_new_pose", detail))


def start_auto(
    campaign_id: int,
    anchor: str,
    known_poses_deg: FloatArray | Sequence[Sequence[float]] | None,
    previous: AutoState | None,
    now: float,
) -> AutoState:
    """The state of auto mode enabled at monotonic ``now`` [s] for ``campaign_id``.

    ``known_poses_deg`` (shape (n, 6) [deg]) are poses captured already; re-enabling the
    campaign of ``previous`` keeps the poses it knew. Raises ``ValueError`` on a bad shape.
    """
    known = np.empty((0, 6))
    if known_poses_deg is not None:
        known = np.asarray(known_poses_deg, dtype=float)
        if known.size == 0:
            known = np.empty((0, 6))
        if known.ndim != 2 or known.shape[1] != 6:
            raise ValueError(f"known_poses_deg: expected shape (n, 6), got {known.shape}")
    if previous is not None and previous.campaign_id == campaign_id:
        known = np.vstack([previous.known, known])
    return AutoState(campaign_id, anchor, known, since=now)
