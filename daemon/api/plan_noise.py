"""The length noise a plan assumes, taken from the cell when the request does not give one.

The plan's predicted σ (:mod:`calib.planning`) scales with the 1σ noise of ONE captured
length. A capture is the mean of a settled window of readings
(:func:`daemon.sampler.settle.make_capture`), so that noise is the standard error of a window mean,
usually far below the indicator's per-reading noise, and an operator cannot guess it.
:func:`cell_noise` takes the best figure the cell has, in this order (``noise_source``; a
``noise_mm`` the request gives, ``request``, wins over all):

1. ``result``: the noise the robot's newest accepted identification ran with
   (``result.prior.noise_mm``, the σ̂ of its own residuals): what the next fit will see,
   including what the model does not explain. A fit with ``weight`` ``fixed`` ran with the
   noise it was given, so its ``noise_estimated_mm`` counts, if any.
2. ``samples``: the campaign's included captures. With repeat poses (two or more samples at
   the same pose and anchor, :func:`calib.planning.progress.match_poses`'s tolerance), the spread of
   their lengths (robot repeatability and drift included). Without, the standard error of
   each capture mean from its ``length_std_mm`` and reading ``count``, corrected for the
   readings' correlation as their raw readings show it (an indicator holds its display
   between updates, so a poll faster than the update rate reads each value more than once):
   a lower bound, as it leaves out what varies between captures.
3. ``sampler``: the live sampler's ring buffer, cut into windows of ``settle_s``; the still
   ones (joints and length within the settle tolerances) give the spread and the reading
   count of a capture window, corrected for correlation the same way. Also a lower bound.
4. ``default``: :class:`calib.planning.PlanOptions`' ``noise_mm``.

The arithmetic is calib's (:mod:`calib.planning.noise`: :func:`~calib.planning.noise.choose`
and the estimates); :func:`cell_noise` reads the store and the sampler.
"""

from __future__ import annotations

from typing import Any

from calib.planning import PlanOptions
from calib.planning.noise import (
    MIN_WINDOWS,
    NOISE_SOURCES,
    NoiseEstimate,
    NoiseSource,
    capture_mean_estimate,
    choose,
    repeat_estimate,
    sampler_estimate,
)
from calib.result import CalibrationResult
from daemon.sampler.config import MAX_BUFFER
from daemon.store import StoreNotFound

#: Captures whose raw readings are read for the correlation (newest first): bounds the I/O.
MAX_RAW_SAMPLES = 50


def _result_noise(store: Any, robot_id: int) -> float | None:
    try:
        result = store.accepted_result(robot_id)["result"]
    except StoreNotFound:
        return None
    loaded = CalibrationResult.from_json(result)
    prior = loaded.prior.block if loaded.prior else {}
    # weight "fixed": noise_mm is the option the fit was given, not what its data said.
    noise = prior.get("noise_estimated_mm" if prior.get("weight") == "fixed" else "noise_mm")
    return None if noise is None else float(noise)


def _samples_noise(store: Any, campaign_id: int) -> NoiseEstimate | None:
    rows = store.list_samples(campaign_id, include_excluded=False, limit=10_000)
    if not rows:
        return None
    samples, _ = store.sample_set(campaign_id)
    repeat = repeat_estimate(
        samples.joints_deg, [str(a) for a in samples.anchor], samples.length_mm
    )
    if repeat is not None:
        return repeat
    stats = [
        (r["length_std_mm"], r["count"], r["id"])
        for r in rows
        if r["length_std_mm"] is not None and r["count"]
    ]
    if len(stats) < MIN_WINDOWS:
        return None  # too few to estimate: read no raw readings
    raw = [
        [float(x["length_mm"]) for x in store.raw_readings(int(sid))]
        for _, _, sid in stats[-MAX_RAW_SAMPLES:]
    ]
    return capture_mean_estimate([(float(s), float(c)) for s, c, _ in stats], raw)


def _sampler_noise(sampler: Any, cfg: Any) -> NoiseEstimate | None:
    recent = getattr(sampler, "recent_readings", None)  # None: no devices (or a test fake)
    if recent is None:
        return None
    buf = recent(0.0, MAX_BUFFER)
    return sampler_estimate(
        [r.t_mono for r in buf],
        [r.joints_deg for r in buf],
        [r.length_mm for r in buf],
        [r.over_range for r in buf],
        cfg.settle_s,
        cfg.settle_tol_deg,
        cfg.settle_tol_mm,
        cfg.min_readings,
    )


def cell_noise(
    store: Any, sampler: Any, sampler_cfg: Any, campaign_id: int, robot_id: int
) -> NoiseEstimate:
    """The cell's best estimate of one capture's length noise (see the module docstring).

    ``sampler`` may be None (no devices); ``sampler_cfg`` has ``settle_s``,
    ``settle_tol_deg``, ``settle_tol_mm`` and ``min_readings``."""
    result = _result_noise(store, robot_id)
    samples = None if result is not None else _samples_noise(store, campaign_id)
    live = (
        None if result is not None or samples is not None else _sampler_noise(sampler, sampler_cfg)
    )
    return choose(result, samples, live, PlanOptions().noise_mm)


__all__ = ["NOISE_SOURCES", "NoiseEstimate", "NoiseSource", "cell_noise"]
