"""The length noise a plan assumes, from the cell's figures: the arithmetic, pure.

The plan's predicted σ (:mod:`calib.planning`) scales with the 1σ noise of ONE captured
length. A capture is the mean of a settled window of readings, so that noise is the standard
error of a window mean, usually far below the indicator's per-reading noise, and an operator
cannot guess it. The daemon (:func:`daemon.api.plan_noise.cell_noise`) reads the cell's figures
(the accepted result, the campaign's captures, the live readings) and :func:`choose` takes
the first usable one, in :data:`NOISE_SOURCES` order; the figures are computed here:
:func:`repeat_estimate` (repeat poses), else :func:`capture_mean_estimate` (each capture
mean's standard error),
:func:`sampler_estimate` (still windows of the live readings), from
:func:`window_mean_se_mm`, :func:`repeat_noise_mm` and :func:`still_windows`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from calib.kinematics import FloatArray
from calib.planning.progress import MATCH_TOL_DEG

NoiseSource = Literal["request", "result", "samples", "sampler", "default"]

#: The sources in the order they are tried (``request``: the plan request gave ``noise_mm``).
NOISE_SOURCES: tuple[NoiseSource, ...] = ("request", "result", "samples", "sampler", "default")
#: Fewest capture windows (or degrees of freedom of repeat poses) an estimate rests on.
MIN_WINDOWS = 3


@dataclass(frozen=True)
class NoiseEstimate:
    """The 1σ noise of one captured length [mm], where it came from, and how, in words."""

    noise_mm: float
    source: NoiseSource
    detail: str


def correlation_factor(windows: Sequence[FloatArray]) -> float:
    """How much more a window mean varies than ``s²/n`` says: ``1 + 2 Σ (1 − k/n) ρ_k``,
    with the lag-k autocorrelation ``ρ_k`` pooled over the windows (each about its own mean)
    and summed while positive. 1 for independent readings, about m for a value read m times.

    Parameters
    ----------
    windows : sequence of ndarray, each shape (n_i,)
        The lengths of each window [mm].
    """
    demeaned = [np.asarray(w, float) - np.mean(w) for w in windows if len(w) > 1]
    if not demeaned:
        return 1.0
    c0 = sum(float(d @ d) for d in demeaned) / sum(len(d) for d in demeaned)
    if c0 <= 0.0:
        return 1.0
    n_mean = float(np.mean([len(d) for d in demeaned]))
    factor = 1.0
    for k in range(1, int(n_mean) // 2 + 1):
        pairs = [(d[:-k], d[k:]) for d in demeaned if len(d) > k]
        count = sum(len(a) for a, _ in pairs)
        if count == 0:
            break
        rho = sum(float(a @ b) for a, b in pairs) / count / c0
        if rho <= 0.0:
            break
        factor += 2.0 * (1.0 - k / n_mean) * rho
    return factor


def window_mean_se_mm(
    std_mm: FloatArray, count: FloatArray, raw_windows: Sequence[FloatArray] = ()
) -> float:
    """The RMS standard error of a window mean [mm]: ``sqrt(mean(s_i² / n_i) · f)``, ``f``
    the :func:`correlation_factor` of ``raw_windows`` (1 without them).

    Parameters
    ----------
    std_mm : ndarray, shape (m,)
        Sample standard deviation of each window's readings [mm].
    count : ndarray, shape (m,)
        Readings in each window [count], ≥ 1.
    raw_windows : sequence of ndarray
        Readings of some of the windows [mm], for the correlation.
    """
    s = np.asarray(std_mm, float)
    n = np.asarray(count, float)
    return float(np.sqrt(np.mean(s**2 / n) * correlation_factor(raw_windows)))


def repeat_noise_mm(
    joints_deg: FloatArray,
    anchors: Sequence[str],
    length_mm: FloatArray,
    tol_deg: float = MATCH_TOL_DEG,
) -> tuple[float, int]:
    """The pooled spread of the lengths of samples at the same pose and anchor (every joint
    within ``tol_deg`` of the group's first sample).

    Parameters
    ----------
    joints_deg : ndarray, shape (n, 6)
        Sample poses [deg].
    anchors : sequence of str, length n
    length_mm : ndarray, shape (n,)
        Captured lengths [mm].

    Returns
    -------
    noise_mm : float
        ``sqrt(Σ_groups Σ (L − mean)² / dof)`` [mm]; NaN when ``dof`` is 0.
    dof : int
        ``Σ_groups (size − 1)``.
    """
    q = np.asarray(joints_deg, float)
    lengths = np.asarray(length_mm, float)
    group = np.full(len(q), -1)
    for i in range(len(q)):
        if group[i] >= 0:
            continue
        same = (np.abs(q - q[i]).max(axis=1) <= tol_deg) & (group < 0)
        same &= np.array([a == anchors[i] for a in anchors])
        group[same] = i
    ss, dof = 0.0, 0
    for g in np.unique(group):
        members = lengths[group == g]
        if len(members) > 1:
            ss += float(np.sum((members - members.mean()) ** 2))
            dof += len(members) - 1
    return (float(np.sqrt(ss / dof)) if dof else float("nan")), dof


def still_windows(
    t_s: FloatArray,
    joints_deg: FloatArray,
    length_mm: FloatArray,
    over_range: FloatArray,
    settle_s: float,
    tol_deg: float,
    tol_mm: float,
    min_readings: int,
) -> list[FloatArray]:
    """The readings cut into consecutive windows of ``settle_s`` (as a capture averages; the
    newest, still filling, left out); those in which the robot was still and the length
    steady, by the settle rules (:mod:`calib.monitor.settle`: ≥ ``min_readings``, no over-range,
    every joint within ``tol_deg`` and the length within ``tol_mm`` of the window mean).

    Parameters
    ----------
    t_s : ndarray, shape (n,)
        Monotonic stamps, non-decreasing [s].
    joints_deg : ndarray, shape (n, 6)
        [deg].
    length_mm : ndarray, shape (n,)
        [mm].
    over_range : ndarray of bool, shape (n,)

    Returns
    -------
    list of ndarray
        Each still window's lengths [mm].
    """
    t = np.asarray(t_s, float)
    if len(t) == 0:
        return []
    idx = np.floor((t - t[0]) / settle_s).astype(int)
    out: list[FloatArray] = []
    for k in np.unique(idx)[:-1]:  # the newest window is still filling: fewer readings
        sel = idx == k
        q, lengths = np.asarray(joints_deg, float)[sel], np.asarray(length_mm, float)[sel]
        if len(lengths) < min_readings or bool(np.any(np.asarray(over_range)[sel])):
            continue
        if not np.all(np.isfinite(lengths)):
            continue
        if np.abs(q - q.mean(axis=0)).max() > tol_deg:
            continue
        if np.abs(lengths - lengths.mean()).max() > tol_mm:
            continue
        out.append(lengths)
    return out


def choose(
    result_mm: float | None,
    samples: NoiseEstimate | None,
    sampler: NoiseEstimate | None,
    default_mm: float,
) -> NoiseEstimate:
    """The first usable estimate in :data:`NOISE_SOURCES` order (finite and > 0)."""

    def usable(x: float | None) -> bool:
        return x is not None and bool(np.isfinite(x)) and x > 0.0

    if usable(result_mm):
        assert result_mm is not None
        return NoiseEstimate(
            float(result_mm),
            "result",
            "the noise the robot's accepted identification ran with (σ̂ of its residuals)",
        )
    for est in (samples, sampler):
        if est is not None and usable(est.noise_mm):
            return est
    return NoiseEstimate(float(default_mm), "default", "the planning default: no cell data yet")


def repeat_estimate(
    joints_deg: FloatArray | Sequence[Sequence[float]],
    anchors: Sequence[str],
    length_mm: FloatArray | Sequence[float],
) -> NoiseEstimate | None:
    """The ``samples`` estimate from repeat poses of a campaign's included captures: the
    spread of their lengths (:func:`repeat_noise_mm`), when it rests on at least
    :data:`MIN_WINDOWS` degrees of freedom; else None.

    Parameters
    ----------
    joints_deg : ndarray, shape (n, 6) [deg]
    anchors : sequence of str, length n
    length_mm : ndarray, shape (n,) [mm]
    """
    rep, dof = repeat_noise_mm(
        np.asarray(joints_deg, float).reshape(-1, 6), list(anchors), np.asarray(length_mm, float)
    )
    if dof < MIN_WINDOWS:
        return None
    return NoiseEstimate(
        rep, "samples", f"the spread of the lengths at repeated poses of the campaign ({dof} dof)"
    )


def capture_mean_estimate(
    stats: Sequence[tuple[float, float]], raw_windows: Sequence[Sequence[float]] = ()
) -> NoiseEstimate | None:
    """The ``samples`` estimate without repeat poses: the standard error of a capture mean
    (:func:`window_mean_se_mm`) from the ``(length_std_mm, count)`` of at least
    :data:`MIN_WINDOWS` captures (else None) and the raw readings [mm] of some of them
    (``raw_windows``, for the correlation). A lower bound: what varies between captures is
    not in it."""
    if len(stats) < MIN_WINDOWS:
        return None
    raw = [np.asarray(w, float) for w in raw_windows if len(w) > 1]
    std = np.array([s for s, _ in stats], float)
    count = np.array([c for _, c in stats], float)
    se = window_mean_se_mm(std, count, raw)
    return NoiseEstimate(
        se,
        "samples",
        f"the standard error of the campaign's {len(stats)} capture means (reading spread, "
        f"count and correlation; a lower bound: no repeated poses to show what varies "
        f"between captures)",
    )


def sampler_estimate(
    t_s: Sequence[float],
    joints_deg: Sequence[Sequence[float]],
    length_mm: Sequence[float],
    over_range: Sequence[bool],
    settle_s: float,
    tol_deg: float,
    tol_mm: float,
    min_readings: int,
) -> NoiseEstimate | None:
    """The ``sampler`` estimate of the live readings (monotonic stamps [s], joints (n, 6)
    [deg], lengths [mm], over-range flags): the standard error of a window mean over their
    :func:`still_windows` (at least :data:`MIN_WINDOWS`, else None)."""
    if not t_s:
        return None
    windows = still_windows(
        np.asarray(t_s, float),
        np.asarray(joints_deg, float).reshape(-1, 6),
        np.asarray(length_mm, float),
        np.asarray(over_range, bool),
        settle_s,
        tol_deg,
        tol_mm,
        min_readings,
    )
    if len(windows) < MIN_WINDOWS:
        return None
    std = np.array([np.std(w, ddof=1) for w in windows])
    count = np.array([len(w) for w in windows], float)
    se = window_mean_se_mm(std, count, windows)
    return NoiseEstimate(
        se,
        "sampler",
        f"the live indicator: {len(windows)} still windows of {settle_s} s, "
        f"{float(np.mean(count)):.0f} readings each (a lower bound: what varies between "
        "captures is not in it)",
    )
