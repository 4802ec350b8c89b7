"""The sampler: polls the indicator and the robot, detects settling, and captures samples.

Each device has its own asyncio loop, so one slow device never slows the other: the
indicator's loop pairs each length with the robot's newest joints into a reading (joint
angles, cable length, monotonic and wall stamps, over-range flag) kept in a ring buffer of
``history_s``; the robot's loop polls once per indicator cycle (waiting at most a tenth of a
settle window for it). The manual robot (no I/O) is read in the indicator's loop. A device
error never stops a loop: it is counted, logged with the device's last frames, recorded as an
event at the start of each error episode, and that device's loop pauses ``error_backoff_s``.

A robot that answers, but whose newest joints are older than ``settle_s``, is ``late``
(:mod:`daemon.sampler.late`: status, ``robot_late`` event, ``cablecal_robot_late_total``);
a settle window needs ``min_readings`` distinct robot readings too, and a pose auto mode
leaves without a capture is counted in ``cablecal_poses_lost_total`` (event ``pose_lost``).

Settling
--------
Settle detection is :func:`daemon.settle.evaluate` (pure: buffer, settings and time in,
verdict out); the window rules are documented there. Each device's state, metrics and events
are kept by a :class:`daemon.devices.Device`.

The indicator's own "moving" status bit is not used: the readings themselves decide. An
over-range reply (flagged, or raised as :class:`~drivers.IndicatorOverRange`) is a reading
without a length: it is counted as a device error but opens no error episode. The manual
robot's angles keep the stamp of their submission, so only the indicator's stamp is checked
for staleness with that driver; a manual robot without angles (``RobotNoData``) is "no data",
not a device error.

A capture is the mean of a settled window (with the sample standard deviation and the count);
no reading ever goes into two captures, and a capture only uses readings polled after it was
requested. It is acknowledged only once :meth:`CaptureSink.store_capture` has committed it.

Modes
-----
``manual``: :meth:`Sampler.capture` waits up to ``capture_timeout_s`` for a settled window.
``auto`` (:meth:`Sampler.set_auto`): the loop captures once at each new settled pose; after a
capture the robot must move before the next, and a pose within ``auto_new_pose_deg`` (every
joint) of a pose already captured in the campaign is never captured again.

Modules
-------
:mod:`daemon.sampler.config` (:class:`SamplerConfig`), :mod:`daemon.sampler.auto` (auto mode's
state and per-cycle decisions), :mod:`daemon.sampler.late` (late robot replies),
:mod:`daemon.sampler.captures` (settle checks and the capture path),
:mod:`daemon.sampler.core` (:class:`Sampler`: the poll loops, auto steps, status;
:func:`build_sampler`). None of them imports numpy (:mod:`daemon.settle` does).
"""

from daemon.sampler.auto import AutoAction, AutoState, start_auto
from daemon.sampler.config import MAX_BUFFER, SamplerConfig
from daemon.sampler.core import Sampler, build_sampler
from daemon.settle import (
    NOT_SETTLED,
    PairedReading,
    Verdict,
    as_joints,
    evaluate,
    make_capture,
    staleness_s,
)

__all__ = [
    "MAX_BUFFER",
    "NOT_SETTLED",
    "AutoAction",
    "AutoState",
    "PairedReading",
    "Sampler",
    "SamplerConfig",
    "Verdict",
    "as_joints",
    "build_sampler",
    "evaluate",
    "make_capture",
    "staleness_s",
    "start_auto",
]
