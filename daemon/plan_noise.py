"""The length noise a plan assumes, taken from the cell when the request does not give one.

The plan's predicted σ (:mod:`calib.planning`) scales with the 1σ noise of ONE captured
length. A capture is the mean of a settled window of readings (:func:`daemon.settle.
make_capture`), so that noise is the standard error of a window mean, usually far below the
indicator's per-reading noise, and an operator cannot guess it. :func:`cell_noise` takes the
best figure the cell has, in this order (``noise_source``; a ``noise_mm`` the request gives,
``request``, wins over all):

1. ``result``: the noise the robot's newest accepted identification ran with
   (``result.prior.noise_mm``, the σ̂ of its own residuals): what the next fit will see,
   including what the model does not explain. A fit with ``weight`` ``fixed`` ran with the
   noise it was given, so its ``noise_estimated_mm`` counts, if any.
2. ``samples``: the campaign's included captures. With repeat poses (two or more samples at
   the same pose and anchor, :func:`daemon.store.match_poses`'s tolerance), the spread of
   their lengths (robot repeatability and drift included). Without, the standard error of
   each capture mean from its ``length_std_mm`` and reading ``count``, corrected for the
   readings' correlation as their raw readings show it (an indicator holds its display
   between updates, so a poll faster than the update rate reads each value more than once):
   a lower bound, as it leaves out what varies between captures.
3. ``sampler``: the live sampler's ring buffer, cut into windows of ``settle_s``; the still
   ones (joints and length within the settle tolerances) give the spread and the reading
   count of a capture window, corrected for correlation the same way. Also a lower bound.
4. ``default``: :class:`calib.planning.PlanOptions`' ``noise_mm``.

The arithmetic (:func:`window_mean_se_mm`, :func:`repeat_noise_mm`, :func:`still_windows`,
:func:`choose`) is pure; :func:`cell_noise` reads the store and the sampler.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from calib.planning import PlanOptions
from daemon.sampler.config import MAX_BUFFER
from daemon.store import MATCH_TOL_DEG, StoreNotFound

FloatArray = NDArray[np.float64]
NoiseSource = Literal["request", "result", "samples", "sampler", "default"]

#: The sources in the order they are tried (``request``: the plan request gave ``noise_mm``).
NOISE_SOURCES: tuple[NoiseSource, ...] = ("request", "result", "samples", "sampler", "default")
#: Fewest capture windows (or degrees of freedom of repeat poses) an estimate rests on.
MIN_WINDOWS = 3
#: Captures whose raw readings are read for the correlation (newest first): bounds the I/O.
MAX_RAW_SAMPLES = 50


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
    joints_deg: FloatArray, anchors: Sequence[str], length_mm: FloatArray,
    tol_deg: float = MATCH_TOL_DEG,
) -> tuple[float, int]:  # fmt: skip
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
    t_s: FloatArray, joints_deg: FloatArray, length_mm: FloatArray, over_range: FloatArray,
    settle_s: float, tol_deg: float, tol_mm: float, min_readings: int,
) -> list[FloatArray]:  # fmt: skip
    """The readings cut into consecutive windows of ``settle_s`` (as a capture averages; the
    newest, still filling, left out); those in which the robot was still and the length
    steady, by the settle rules (:mod:`daemon.settle`: ≥ ``min_readings``, no over-range,
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
    result_mm: float | None, samples: NoiseEstimate | None, sampler: NoiseEstimate | None,
    default_mm: float,
) -> NoiseEstimate:  # fmt: skip
    """The first usable estimate in :data:`NOISE_SOURCES` order (finite and > 0)."""

    def usable(x: float | None) -> bool:
        return x is not None and bool(np.isfinite(x)) and x > 0.0

    if usable(result_mm):
        assert result_mm is not None
        return NoiseEstimate(
            float(result_mm), "result",
            "the noise the robot's accepted identification ran with (σ̂ of its residuals)",
        )  # fmt: skip
    for est in (samples, sampler):
        if est is not None and usable(est.noise_mm):
            return est
    return NoiseEstimate(float(default_mm), "default", "the planning default: no cell data yet")


def _result_noise(store: Any, robot_id: int) -> float | None:
    try:
        result = store.accepted_result(robot_id)["result"]
    except StoreNotFound:
        return None
    prior = result.get("prior") or {}
    # weight "fixed": noise_mm is the option the fit was given, not what its data said.
    noise = prior.get("noise_estimated_mm" if prior.get("weight") == "fixed" else "noise_mm")
    return None if noise is None else float(noise)


def _samples_noise(store: Any, campaign_id: int) -> NoiseEstimate | None:
    rows = store.list_samples(campaign_id, include_excluded=False, limit=10_000)
    if not rows:
        return None
    samples, _ = store.sample_set(campaign_id)
    rep, dof = repeat_noise_mm(samples.joints_deg, [str(a) for a in samples.anchor],
                               samples.length_mm)  # fmt: skip
    if dof >= MIN_WINDOWS:
        return NoiseEstimate(
            rep, "samples",
            f"the spread of the lengths at repeated poses of the campaign ({dof} dof)",
        )  # fmt: skip
    stats = [(r["length_std_mm"], r["count"], r["id"]) for r in rows
             if r["length_std_mm"] is not None and r["count"]]  # fmt: skip
    if len(stats) < MIN_WINDOWS:
        return None
    raw = []
    for _, _, sid in stats[-MAX_RAW_SAMPLES:]:
        lengths = [float(x["length_mm"]) for x in store.raw_readings(int(sid))]
        if len(lengths) > 1:
            raw.append(np.asarray(lengths, float))
    std = np.array([s for s, _, _ in stats], float)
    count = np.array([c for _, c, _ in stats], float)
    se = window_mean_se_mm(std, count, raw)
    return NoiseEstimate(
        se, "samples",
        f"the standard error of the campaign's {len(stats)} capture means (reading spread, "
        f"count and correlation; a lower bound: no repeated poses to show what varies "
        f"between captures)",
    )  # fmt: skip


def _sampler_noise(sampler: Any, cfg: Any) -> NoiseEstimate | None:
    recent = getattr(sampler, "recent_readings", None)  # None: no devices (or a test fake)
    if recent is None:
        return None
    buf = recent(0.0, MAX_BUFFER)
    if not buf:
        return None
    windows = still_windows(
        np.array([r.t_mono for r in buf]), np.array([r.joints_deg for r in buf]),
        np.array([r.length_mm for r in buf]), np.array([r.over_range for r in buf]),
        cfg.settle_s, cfg.settle_tol_deg, cfg.settle_tol_mm, cfg.min_readings,
    )  # fmt: skip
    if len(windows) < MIN_WINDOWS:
        return None
    std = np.array([np.std(w, ddof=1) for w in windows])
    count = np.array([len(w) for w in windows], float)
    se = window_mean_se_mm(std, count, windows)
    return NoiseEstimate(
        se, "sampler",
        f"the live indicator: {len(windows)} still windows of {cfg.settle_s} s, "
        f"{float(np.mean(count)):.0f} readings each (a lower bound: what varies between "
        "captures is not in it)",
    )  # fmt: skip


def cell_noise(
    store: Any, sampler: Any, sampler_cfg: Any, campaign_id: int, robot_id: int
) -> NoiseEstimate:
    """The cell's best estimate of one capture's length noise (see the module docstring).

    ``sampler`` may be None (no devices); ``sampler_cfg`` has ``settle_s``,
    ``settle_tol_deg``, ``settle_tol_mm`` and ``min_readings``."""
    result = _result_noise(store, robot_id)
    samples = None if result is not None else _samples_noise(store, campaign_id)
    live = None if result is not None or samples is not None else _sampler_noise(
        sampler, sampler_cfg
    )  # fmt: skip
    return choose(result, samples, live, PlanOptions().noise_mm)


__all__ = [
    "NOISE_SOURCES",
    "NoiseEstimate",
    "NoiseSource",
    "cell_noise",
    "choose",
    "correlation_factor",
    "repeat_noise_mm",
    "still_windows",
    "window_mean_se_mm",
]
