"""Settle detection: pure functions of paired readings and time.

Nothing here does I/O, reads a clock or touches asyncio: :func:`evaluate` takes a buffer of
:class:`PairedReading` (oldest first), the settings and the current monotonic time, and returns
a :class:`Verdict`; :func:`window_stats` gives a settled window's means and spreads, of which
the daemon builds a capture (:func:`daemon.sampler.settle.make_capture`). The sampler
(:mod:`daemon.sampler`) owns the buffer and calls them each poll cycle, the way pymodbus'
framer turns bytes into frames apart from its transport.

Settling
--------
The window is the last ``settle_s`` of paired readings, ending at the newest one. It is
settled when all of these hold:

* the newest reading is at most ``stale_s`` old, and no gap between consecutive readings
  (including the one just before the window) exceeds ``stale_s``: the window is covered;
* it holds at least ``min_readings`` readings, with at least ``min_readings`` distinct robot
  readings among them (the robot is polled on its own: a slow robot's one reading paired with
  many lengths says nothing about whether it stood still);
* no reading is stale (each stamp at most ``stale_s`` old when paired, and the two devices'
  stamps at most ``stale_s`` apart);
* no reading is over-range;
* every joint stays within ``settle_tol_deg`` and the length within ``settle_tol_mm`` of the
  window mean.

The checks run in that order and the first that fails gives the verdict's reason.

A frozen controller
-------------------
A controller that stops updating its joint angles while the robot moves gives bit-identical
joints with fresh stamps: every settle check passes once the robot stops at its next pose,
and the sample would pair the new length with the old joints. :class:`FrozenWatch`, fed
every paired reading, catches it: while the joints stay bit-identical, a cable length that
differs from the run's reference (the first reading of the run, or the oldest one within
``history_s``) by more than ``settle_tol_mm`` in ``min_readings`` readings in a row marks
those joints frozen (verdict ``frozen``), until the controller reports other joints. The
reference slides with ``history_s``, so a slow thermal drift at rest is not a freeze; a robot
at rest whose cable is moved by hand is refused the same way (its joints did not follow the
cable), which the refusal's words say.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal, Protocol

import numpy as np

from calib.kinematics import FloatArray
from calib.sample_fields import Joints

#: Why a window is not settled (a subset of the daemon's capture rejection reasons,
#: :data:`daemon.sampler.capture.RejectionReason`).
SettleReason = Literal["moving", "over_range", "stale", "no_data", "frozen"]


class SettleConfig(Protocol):
    """The settings :func:`evaluate` reads (the daemon's ``SamplerConfig`` has them)."""

    @property
    def settle_s(self) -> float:
        """Window in which the robot must be still [s]."""
        ...

    @property
    def settle_tol_mm(self) -> float:
        """Largest deviation of the cable length from the window mean [mm]."""
        ...

    @property
    def settle_tol_deg(self) -> float:
        """Largest deviation of each joint from the window mean [deg]."""
        ...

    @property
    def stale_s(self) -> float:
        """Largest reading age, stamp skew and gap between readings [s]."""
        ...

    @property
    def min_readings(self) -> int:
        """Fewest paired readings in a settled window [count]."""
        ...


@dataclass(frozen=True, slots=True)
class PairedReading:
    """One paired poll of both devices. Monotonic times in s.

    Attributes
    ----------
    t_poll : float
        Monotonic time the poll started [s].
    t_mono, t_wall : float
        Monotonic and wall stamps of the length reading [s].
    joints_deg : Joints
        Joint angles [deg].
    length_mm : float
        Cable length [mm]; NaN when the indicator raised over-range (no value).
    over_range : bool
    staleness_s : float
        Worst of: the stamps' ages at pairing, the skew between the two stamps [s].
    t_joints : float
        Monotonic stamp of the robot reading [s]; NaN for the manual robot (its angles are
        typed in, one submission for every pairing).
    """

    t_poll: float
    t_mono: float
    t_wall: float
    joints_deg: Joints
    length_mm: float
    over_range: bool
    staleness_s: float
    t_joints: float = math.nan


@dataclass(frozen=True)
class Verdict:
    """Outcome of a settle check: ``reason is None`` means settled (``window`` is set).

    ``final``: waiting longer will not help while the robot stays (e.g. still but over-range).
    ``joints_still``: the joints are within tolerance over a covered window (None: unknown).
    """

    reason: SettleReason | None
    detail: str
    final: bool = False
    joints_still: bool | None = None
    window: tuple[PairedReading, ...] = ()


#: Smallest change of the cable length [mm] that can say a controller is frozen: well above a
#: real indicator's noise (hundredths of a mm) and the emulated cell's (tenths), so noise at rest
#: never trips it; a frozen controller during a move between calibration poses changes the
#: length by tens of millimetres.
FROZEN_MIN_CHANGE_MM = 1.0


class FrozenWatch:
    """The robot's joints bit-identical while the cable length moved (see the module).

    Evidence is counted in distinct controller replies (``t_joints``), not in indicator
    readings: under load the robot's poll lags, and many indicator readings are paired with one
    old reply while the robot moves, which is no frozen controller.

    Feed every paired reading to :meth:`add`, oldest first, with the oldest reading of the
    sampler's buffer; :meth:`verdict` is the ``frozen`` verdict while the newest joints are the
    frozen ones, else None. O(1) per reading. A manual robot (``t_joints`` NaN: its angles are
    typed in and repeat by design) is never frozen.
    """

    def __init__(self, tol_mm: float, min_readings: int, min_duration_s: float = 0.0) -> None:
        self.tol_mm = max(tol_mm, FROZEN_MIN_CHANGE_MM)
        self.min_readings = min_readings
        #: The change must last this long [s] (the sampler's settle window): a controller
        #: reports its joints some milliseconds late, so as a move starts the cable moves
        #: before the joints do; that is latency, not a frozen controller.
        self.min_duration_s = min_duration_s
        self._t_far = math.nan  # t_mono of the first reading of the current far run [s]
        self._q: Joints | None = None
        self._t_start = math.nan  # t_mono of the run's first reading [s]
        self._ref_start_mm = math.nan  # its length [mm]
        self._far = 0  # distinct robot replies in a row beyond tol_mm of the reference
        self._t_reply = math.nan  # t_joints of the last reply counted in _far [s]
        self._frozen: Joints | None = None
        self._moved_mm = 0.0  # the largest length change seen while frozen [mm]

    def add(self, reading: PairedReading, oldest: PairedReading) -> None:
        """Book ``reading`` (the newest); ``oldest``: the buffer's oldest reading."""
        if math.isnan(reading.t_joints):
            self._q = self._frozen = None
            return
        if reading.joints_deg != self._q:
            self._q, self._frozen, self._far = reading.joints_deg, None, 0
            self._t_reply = math.nan
            self._t_start, self._ref_start_mm, self._moved_mm = reading.t_mono, math.nan, 0.0
        if reading.over_range or not math.isfinite(reading.length_mm):
            return
        if math.isnan(self._ref_start_mm):
            self._ref_start_mm = reading.length_mm
            return
        slid = oldest.t_mono > self._t_start and math.isfinite(oldest.length_mm)
        ref = oldest.length_mm if slid and not oldest.over_range else self._ref_start_mm
        change = abs(reading.length_mm - ref)
        if change <= self.tol_mm:
            self._far = 0
        elif not reading.t_joints <= self._t_reply:
            # Only a new reply of the controller counts: indicator readings paired with the
            # same (late) robot reply are no evidence that the controller stopped updating.
            if self._far == 0:
                self._t_far = reading.t_mono
            self._far += 1
            self._t_reply = reading.t_joints
        lasted = reading.t_mono - self._t_far >= self.min_duration_s
        if self._far >= self.min_readings and lasted:
            self._frozen = self._q
            self._moved_mm = max(self._moved_mm, change)

    def verdict(self, latest: PairedReading | None) -> Verdict | None:
        """The ``frozen`` verdict while ``latest`` carries the frozen joints, else None."""
        if self._frozen is None or latest is None or latest.joints_deg != self._frozen:
            return None
        return Verdict(
            "frozen",
            f"the cable length changed by up to {self._moved_mm:.1f} mm while the robot's joint "
            "angles stayed exactly the same: the robot controller is not updating its joints "
            "(frozen), or the cable was moved by hand. No sample is taken until the controller "
            "reports new joint angles: check the controller's connection and move the robot",
            final=True,
            joints_still=True,
        )


#: The verdict before any paired reading.
NOT_SETTLED = Verdict("no_data", "no paired reading yet")


def as_joints(values: Sequence[float] | FloatArray) -> Joints:
    """The first six values as a :data:`Joints` tuple of floats [deg]."""
    v = [float(x) for x in values]
    return (v[0], v[1], v[2], v[3], v[4], v[5])


def staleness_s(t_done: float, t_length: float, t_joints: float, manual_robot: bool) -> float:
    """Staleness of a reading paired at ``t_done`` from a length stamped ``t_length`` and joints
    stamped ``t_joints`` (monotonic [s]): the older stamp's age and the skew between them.

    A manual robot's angles keep the stamp of their submission, so only the length's age counts.
    """
    if manual_robot:
        return t_done - t_length
    return max(t_done - min(t_length, t_joints), abs(t_length - t_joints))


def _window(
    buffer: Sequence[PairedReading], start: float
) -> tuple[list[PairedReading], PairedReading | None]:
    """The readings stamped at or after ``start`` (oldest first), and the one just before."""
    window: list[PairedReading] = []
    before: PairedReading | None = None
    for r in reversed(buffer):
        if r.t_mono < start:
            before = r
            break
        window.append(r)
    window.reverse()
    return window, before


def _coverage(
    window: Sequence[PairedReading], before: PairedReading | None, start: float, cfg: SettleConfig
) -> Verdict | None:
    """A ``stale`` verdict when the window has a gap over ``stale_s`` or too few readings."""
    t_prev = before.t_mono if before is not None else start
    gaps = np.diff(np.array([t_prev, *(r.t_mono for r in window)]))
    if gaps.max() > cfg.stale_s:
        return Verdict("stale", f"gap of {gaps.max():.2f} s between readings (stale_s)")
    if len(window) < cfg.min_readings:
        return Verdict(
            "stale",
            f"{len(window)} readings in {cfg.settle_s} s, fewer than min_readings "
            f"{cfg.min_readings}",
        )
    return None


def _spread(window: Sequence[PairedReading], cfg: SettleConfig, device: str) -> Verdict:
    """The verdict of a covered window: stale stamps, over-range, moving joints or length,
    else settled. ``device`` names the indicator in the over-range detail."""
    q = np.array([r.joints_deg for r in window])  # shape (n, 6) [deg]
    dev_deg = np.abs(q - q.mean(axis=0)).max(axis=0)  # shape (6,) [deg]
    still = bool(dev_deg.max() <= cfg.settle_tol_deg)
    robot = {r.t_joints for r in window if not math.isnan(r.t_joints)}
    if robot and len(robot) < cfg.min_readings:
        return Verdict(
            "stale",
            f"{len(robot)} robot readings in {cfg.settle_s} s, fewer than min_readings "
            f"{cfg.min_readings}: the robot answers late",
            joints_still=still if len(robot) > 1 else None,
        )
    worst = max(window, key=lambda r: r.staleness_s)
    if worst.staleness_s > cfg.stale_s:
        return Verdict(
            "stale",
            f"a reading's stamps are {worst.staleness_s:.2f} s old or apart (stale_s)",
            joints_still=still,
        )
    if any(r.over_range for r in window):
        return Verdict(
            "over_range",
            f"the indicator ({device}) reads over or under its range: move the robot so the "
            "cable stays within the sensor's stroke",
            final=still,
            joints_still=still,
        )
    if not still:
        j = int(np.argmax(dev_deg))
        return Verdict(
            "moving",
            f"joint {j + 1} varies by {dev_deg[j]:.4f} deg (settle_tol_deg {cfg.settle_tol_deg})",
            joints_still=False,
        )
    lengths = np.array([r.length_mm for r in window])  # shape (n,) [mm]
    dev_mm = float(np.abs(lengths - lengths.mean()).max())
    if dev_mm > cfg.settle_tol_mm:
        return Verdict(
            "moving",
            f"cable length varies by {dev_mm:.3f} mm (settle_tol_mm {cfg.settle_tol_mm})",
            joints_still=True,
        )
    return Verdict(None, "settled", joints_still=True, window=tuple(window))


def evaluate(
    buffer: Sequence[PairedReading],
    config: SettleConfig,
    now: float,
    not_before: float = -math.inf,
    device: str = "indicator",
) -> Verdict:
    """Settle check of the window ending at the newest reading of ``buffer``.

    Parameters
    ----------
    buffer : sequence of PairedReading
        Paired readings, oldest first (stamps ``t_mono`` non-decreasing).
    config : SettleConfig
        ``settle_s``, ``stale_s``, ``min_readings``, ``settle_tol_deg``, ``settle_tol_mm``.
    now : float
        Current monotonic time [s].
    not_before : float
        Monotonic time [s]: the newest reading must have been polled at or after it, and the
        whole window must lie after it (a capture only uses readings polled after its request).
    device : str
        Name of the indicator, for the over-range detail.

    Returns
    -------
    Verdict
        ``reason``: None (settled, ``window`` holds its readings), ``no_data`` (no reading
        polled since ``not_before``), ``stale``, ``moving``, or ``over_range``; ``detail``
        says why in words.
    """
    if not buffer or buffer[-1].t_poll < not_before:
        return Verdict("no_data", "no paired reading yet")
    latest = buffer[-1]
    age = now - latest.t_mono
    if age > config.stale_s:
        return Verdict("stale", f"newest paired reading is {age:.2f} s old (stale_s)")
    start = latest.t_mono - config.settle_s
    window, before = _window(buffer, start)
    if start < not_before or window[0].t_poll < not_before:
        return Verdict("moving", "collecting a settle window after the request")
    uncovered = _coverage(window, before, start, config)
    if uncovered is not None:
        return uncovered
    return _spread(window, config, device)


@dataclass(frozen=True)
class WindowStats:
    """Means and sample standard deviations (ddof 1; 0 for one reading) of a window.

    Attributes
    ----------
    joints_deg, joints_std_deg : Joints
        Per joint [deg].
    length_mm, length_std_mm : float
        Of the cable length [mm].
    count : int
        Readings in the window.
    """

    joints_deg: Joints
    joints_std_deg: Joints
    length_mm: float
    length_std_mm: float
    count: int


def window_stats(window: Sequence[PairedReading]) -> WindowStats:
    """The :class:`WindowStats` of a settled window (non-empty)."""
    q = np.array([r.joints_deg for r in window], dtype=float)  # shape (n, 6) [deg]
    lengths = np.array([r.length_mm for r in window], dtype=float)  # shape (n,) [mm]
    ddof = 1 if len(window) > 1 else 0
    return WindowStats(
        joints_deg=as_joints(q.mean(axis=0)),
        joints_std_deg=as_joints(q.std(axis=0, ddof=ddof)),
        length_mm=float(lengths.mean()),
        length_std_mm=float(lengths.std(ddof=ddof)),
        count=len(window),
    )


__all__ = [
    "NOT_SETTLED",
    "FrozenWatch",
    "PairedReading",
    "SettleConfig",
    "SettleReason",
    "Verdict",
    "WindowStats",
    "as_joints",
    "evaluate",
    "staleness_s",
    "window_stats",
]
