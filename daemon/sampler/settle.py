"""Settle detection for the sampler, and capture building.

The decision is calib's (:mod:`calib.monitor.settle`: :func:`evaluate` takes a buffer of
:class:`PairedReading`, the settings and the current monotonic time, and returns a
:class:`Verdict`); it is re-exported here for the sampler, which owns the buffer and calls it
each poll cycle. :func:`make_capture` turns a settled window into the daemon's
:class:`daemon.sampler.capture.Capture`, with the window's readings kept as raw readings.
"""

from __future__ import annotations

from collections.abc import Sequence

from calib.monitor.settle import (
    NOT_SETTLED,
    FrozenWatch,
    PairedReading,
    SettleConfig,
    Verdict,
    as_joints,
    evaluate,
    staleness_s,
    window_stats,
)
from daemon.sampler.capture import Capture, CaptureMode, RawReading


def make_capture(window: Sequence[PairedReading], anchor: str, mode: CaptureMode) -> Capture:
    """The :class:`Capture` of a settled window: means, sample standard deviations (ddof 1)
    and count of the readings (:func:`calib.monitor.settle.window_stats`), which are kept as
    raw readings."""
    stats = window_stats(window)
    return Capture(
        joints_deg=stats.joints_deg,
        joints_std_deg=stats.joints_std_deg,
        length_mm=stats.length_mm,
        length_std_mm=stats.length_std_mm,
        count=stats.count,
        anchor=anchor,
        t_start_wall=window[0].t_wall,
        t_end_wall=window[-1].t_wall,
        mode=mode,
        raw=tuple(RawReading(r.t_wall, r.joints_deg, r.length_mm) for r in window),
    )


__all__ = [
    "NOT_SETTLED",
    "FrozenWatch",
    "PairedReading",
    "SettleConfig",
    "Verdict",
    "as_joints",
    "evaluate",
    "make_capture",
    "staleness_s",
]
