"""Auto capture: the state of one campaign in auto mode and the decision taken each poll cycle.

The sampler calls :meth:`AutoState.decide` after each cycle with the settle verdict and any
device fault; the decision is one of: do nothing, record a rejection, or store the settled
window. The sampler carries it out (:meth:`daemon.sampler.Sampler._auto_step`) and reports a
failed store back with :meth:`AutoState.store_failed`.

Rules: the loop captures once at each new settled pose; after a capture (or a refusal) the robot
must move before the next, and a pose within ``auto_new_pose_deg`` (every joint) of a pose
already captured in the campaign is never captured again. A device fault is recorded once per
error episode; a pose that cannot settle (still but over-range, or still for longer than
``capture_timeout_s`` without settling) is recorded once until the robot moves. A pose the
robot stood still at and left again with neither a capture nor a recorded rejection is *lost*:
the action names why no window settled there (``robot_late`` when the robot's joints came
late while it stood there, else the last verdict's reason), and the sampler counts it.

Plain Python (poses are 6-tuples [deg]): the sampler imports no numpy of its own.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, replace

from calib.dataset import known_pose_index
from calib.sample_fields import Joints
from daemon.sampler.capture import CaptureRejected
from daemon.sampler.config import SamplerConfig
from daemon.sampler.devices import Device
from daemon.sampler.settle import Verdict, as_joints

#: Why a pose was lost beyond a verdict's reasons: the robot's joints came late there.
ROBOT_LATE = "robot_late"


@dataclass(frozen=True)
class AutoAction:
    """What the sampler does after an auto step: record ``reject``, or store the window;
    ``lost``: the robot left a still pose without a capture, and why (to be counted)."""

    reject: CaptureRejected | None = None
    store: bool = False
    lost: str | None = None


def _max_deviation_deg(a: Sequence[float], b: Sequence[float]) -> float:
    """Largest joint difference of two poses [deg]."""
    return max(abs(x - y) for x, y in zip(a, b, strict=True))


def mean_pose(window: Iterable[Sequence[float]]) -> Joints:
    """The joint-wise mean [deg] of poses (6-sequences) in ``window``."""
    rows = list(window)
    return as_joints([sum(column) / len(rows) for column in zip(*rows, strict=True)])


#: Nothing to do this cycle.
NOTHING = AutoAction()


@dataclass
class AutoState:
    """Auto-capture state of one campaign."""

    campaign_id: int
    anchor: str
    known: list[Joints]  # poses captured in the campaign [deg]
    since: float  # monotonic time auto mode was enabled
    need_motion: bool = False  # captured (or refused) here: wait until the robot moves
    pose_ref: Joints | None = None  # where need_motion was set [deg]
    still_since: float | None = None
    still_reason: str | None = None  # why the last window at the still pose did not settle
    late_at_pose: bool = False  # the robot's joints came late while it stood still here
    pose_done: bool = False  # captured or refused at the current still pose
    pose_recorded: bool = False  # a rejection was recorded at the current pose
    reported_known: set[int] = field(default_factory=set)  # not_new_pose recorded per pose
    fault_keys: set[tuple[str, int]] = field(default_factory=set)  # (device, episode)
    retry_after: float = 0.0  # after a failed store

    def stay(self, joints_deg: Joints) -> None:
        """Captured or refused at this pose: the robot must move before the next capture."""
        self.need_motion, self.pose_ref, self.pose_done = True, joints_deg, True

    def saw_joints(self, joints_deg: Joints, tol_deg: float) -> None:
        """A robot reading (paired or not): once the robot left the pose, clear
        ``need_motion`` and ``pose_recorded``."""
        ref = self.pose_ref
        if ref is not None and _max_deviation_deg(ref, joints_deg) > tol_deg:
            self.need_motion = self.pose_recorded = False
            self.pose_ref = None

    def captured(self, pose_deg: Joints) -> None:
        """A capture at ``pose_deg`` [deg] was stored in this campaign."""
        self.known.append(pose_deg)
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
        robot_late: bool = False,
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
        robot_late : bool
            The robot's newest joints are older than the settle window.
        """
        lost = self._track_stillness(verdict, now, robot_late)
        action = self._act(verdict, fault, now, cfg, last_joints_deg)
        return action if lost is None else replace(action, lost=lost)

    def _track_stillness(self, verdict: Verdict, now: float, robot_late: bool) -> str | None:
        """Follow the robot's stillness; the reason a pose was lost when it leaves one."""
        lost = None
        if verdict.joints_still is False:
            if self.still_since is not None and not self.pose_done:
                lost = ROBOT_LATE if self.late_at_pose else self.still_reason or "moving"
            self.need_motion = self.pose_recorded = self.late_at_pose = self.pose_done = False
            self.still_since = self.still_reason = None
        elif verdict.joints_still:
            if self.still_since is None:
                self.still_since = now
            if verdict.reason is not None:
                self.still_reason = verdict.reason
        if robot_late and self.still_since is not None:
            self.late_at_pose = True
        return lost

    def _act(
        self,
        verdict: Verdict,
        fault: tuple[CaptureRejected, Device] | None,
        now: float,
        cfg: SamplerConfig,
        last_joints_deg: Joints | None,
    ) -> AutoAction:
        if fault is not None:
            rejection, dev = fault
            key = (dev.role, dev.episode)
            if key in self.fault_keys:
                return NOTHING
            self.fault_keys.add(key)
            self.pose_done = self.pose_done or self.still_since is not None  # recorded here
            return AutoAction(reject=rejection)
        if verdict.reason is None:
            return self._settled(verdict, now, cfg)
        if verdict.joints_still and not self.need_motion and not self.pose_recorded:
            stuck = self.still_since is not None and now - self.still_since > cfg.capture_timeout_s
            if verdict.final or stuck:
                self.pose_recorded = self.pose_done = True
                if last_joints_deg is not None:
                    self.pose_ref = last_joints_deg
                return AutoAction(reject=CaptureRejected(verdict.reason, verdict.detail))
        return NOTHING

    def _settled(self, verdict: Verdict, now: float, cfg: SamplerConfig) -> AutoAction:
        """A settled window: store it unless the robot has not moved or the pose is known."""
        if self.need_motion or now < self.retry_after:
            return NOTHING
        q = mean_pose(r.joints_deg for r in verdict.window)
        index = known_pose_index(self.known, q, cfg.auto_new_pose_deg)  # the one repeat rule
        if index is None:
            return AutoAction(store=True)
        self.stay(q)
        if index in self.reported_known:
            return NOTHING
        self.reported_known.add(index)
        detail = f"pose {[round(v, 3) for v in q]} deg was captured already"
        return AutoAction(reject=CaptureRejected("not_new_pose", detail))


def start_auto(
    campaign_id: int,
    anchor: str,
    known_poses_deg: Iterable[Sequence[float]] | None,
    previous: AutoState | None,
    now: float,
) -> AutoState:
    """The state of auto mode enabled at monotonic ``now`` [s] for ``campaign_id``.

    ``known_poses_deg`` (shape (n, 6) [deg], rows of any sequence type) are poses captured
    already; re-enabling the campaign of ``previous`` keeps the poses it knew. Raises
    ``ValueError`` when a row does not hold 6 values.
    """
    known: list[Joints] = []
    for row in known_poses_deg if known_poses_deg is not None else ():
        values = [float(v) for v in row]
        if len(values) != 6:
            raise ValueError(f"known_poses_deg: expected shape (n, 6), got a row of {len(values)}")
        known.append(as_joints(values))
    if previous is not None and previous.campaign_id == campaign_id:
        known = [*previous.known, *known]
    return AutoState(campaign_id, anchor, known, since=now)
