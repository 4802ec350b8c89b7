"""Pure decisions of the live sensor watch (:mod:`daemon.monitors.watch`): no I/O, no asyncio.

Two questions a plant engineer asks while a campaign runs or a check comes back:

1. **Did the sensor move?** :class:`StepDetector` takes, sample by sample, the residual of
   each new sample against the campaign's running fit (measured minus predicted cable length
   [mm]; the fit never saw that sample) and flags a step: a bumped sensor stand (a new P0) or
   a re-zeroed indicator (a new offset).

   The test is sequential and robust. A sample *exceeds* when its residual, less the level of
   the recent clean residuals (their median, which follows a slow drift), is beyond the band
   ``max(k_sigma × scale, min_step_mm / 2)``; ``scale`` is the MAD-based sigma of the recent
   clean residuals (before 5 are known: ``prior_scale_mm``, the fit's own residual RMSE), at
   least ``sigma_floor_mm``. A CUSUM of exceedances (+1 beyond the band, −``clean_decay``
   inside) opens a run at the first exceedance and closes it when it falls back to 0; an
   alarm needs ``min_run`` exceedances within one run, so one outlier (or two) is never a
   move, while a pose whose cable happens to be square to the bump (inside the band) does
   not end the run.
   Exceedances of either sign count, so a bump across the cable, which lengthens some poses'
   cable and shortens others', is seen as well as one along it. The run's first sample is
   where the sensor moved; the alarm names it and the median length change.

2. **Robot or sensor?** :func:`explain_change` fits both explanations to a hold check's
   residuals: a point shift of the anchor plus an offset change (4 parameters: every pose's
   length changes by ``−u·δ + Δc``, ``u`` the cable direction) or the offset alone (a
   re-zeroed indicator), against one joint's zero offset plus an offset change (2 parameters,
   the best of the six joints). The two change lengths
   differently over well-spread poses; a BIC comparison names ``sensor``, ``robot`` or
   ``unclear`` (too few poses, or neither explanation clearly better).

Also :func:`locate_step`: after an alarm, where among the recent samples the sensor moved
(the run's first exceedance can be late: a pose square to the bump changes little), and
:func:`next_anchor`: the id of the new anchor session after a move.
"""

from __future__ import annotations

import math
import re
from collections import deque
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from calib.kinematics import FloatArray

#: MAD → sigma for Gaussian residuals.
MAD_TO_SIGMA = 1.4826


@dataclass(frozen=True)
class StepSettings:
    """Tuning of :class:`StepDetector` (the defaults are the daemon's; see the module)."""

    min_step_mm: float = 1.0  # smallest length change called a move [mm]
    sigma_floor_mm: float = 0.05  # the scale never goes below this [mm]
    k_sigma: float = 5.0  # band half-width in scales
    min_run: int = 3  # exceedances within one run needed for an alarm
    clean_decay: float = 0.5  # CUSUM decrement per sample inside the band
    history: int = 30  # clean residuals kept for level and scale

    def __post_init__(self) -> None:
        for name in ("min_step_mm", "sigma_floor_mm", "k_sigma", "clean_decay"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name}: must be a finite number > 0, got {value!r}")
        if self.min_run < 2:
            raise ValueError(f"min_run: must be at least 2, got {self.min_run}")
        if self.history < 5:
            raise ValueError(f"history: must be at least 5, got {self.history}")


@dataclass(frozen=True)
class StepAlarm:
    """A detected step.

    Attributes
    ----------
    first_key : int
        Key (sample id) of the run's first sample: where the sensor moved.
    keys : tuple
        Keys of every sample since then (in order), exceeding or not: they belong to the new
        sensor position.
    step_mm : float
        Median length change of the exceeding samples (signed) [mm].
    size_mm : float
        Median absolute length change of the exceeding samples [mm].
    delay : int
        Samples from the first of the run to the alarm, both counted.
    """

    first_key: int
    keys: tuple[int, ...]
    step_mm: float
    size_mm: float
    delay: int


@dataclass
class StepDetector:
    """Sequential step test on prediction residuals (see the module docstring)."""

    settings: StepSettings = field(default_factory=StepSettings)
    _clean: deque[float] = field(init=False)
    _run: list[tuple[int, float, bool]] = field(init=False, default_factory=list)
    _score: float = field(init=False, default=0.0)
    #: Scale [mm] to use until 5 clean residuals are known (e.g. the fit's residual RMSE).
    prior_scale_mm: float = 0.0

    def __post_init__(self) -> None:
        self._clean = deque(maxlen=self.settings.history)

    def reset(self) -> None:
        """Forget everything (after a move: the new anchor session starts afresh)."""
        self._clean.clear()
        self._run.clear()
        self._score = 0.0

    @property
    def level_mm(self) -> float:
        """Median of the recent clean residuals [mm] (0 before any)."""
        return float(np.median(self._clean)) if self._clean else 0.0

    @property
    def scale_mm(self) -> float:
        """Robust sigma of the recent clean residuals [mm], at least the floor."""
        floor = self.settings.sigma_floor_mm
        if len(self._clean) < 5:
            return max(floor, self.prior_scale_mm)
        r = np.asarray(self._clean)
        return max(floor, MAD_TO_SIGMA * float(np.median(np.abs(r - np.median(r)))))

    @property
    def band_mm(self) -> float:
        """Half-width of the band beyond which a residual exceeds [mm]."""
        s = self.settings
        return max(s.k_sigma * self.scale_mm, s.min_step_mm / 2.0)

    @property
    def suspects(self) -> tuple[int, ...]:
        """Keys of the samples of the current run (not yet an alarm): a fit should leave
        them out."""
        return tuple(key for key, _, _ in self._run)

    def update(self, key: int, residual_mm: float) -> StepAlarm | None:
        """Take one sample's residual [mm]; an alarm or None. A non-finite residual raises
        ``ValueError`` naming the key."""
        if not math.isfinite(residual_mm):
            raise ValueError(f"residual_mm of sample {key!r}: not finite: {residual_mm!r}")
        d = residual_mm - self.level_mm
        exceeds = abs(d) > self.band_mm
        if exceeds:
            self._score += 1
            self._run.append((key, d, True))
        elif self._run:
            self._score = max(0.0, self._score - self.settings.clean_decay)
            self._run.append((key, d, False))
        else:
            self._clean.append(residual_mm)
        if not self._run:
            return None
        if self._score <= 0.0:
            # The run died out: its samples were outliers; the clean ones rejoin the history.
            for _, dev, bad in self._run:
                if not bad:
                    self._clean.append(dev + self.level_mm)
            self._run.clear()
            return None
        over = [dev for _, dev, bad in self._run if bad]
        if len(over) >= self.settings.min_run:
            step = float(np.median(over))
            size = float(np.median(np.abs(over)))
            alarm = StepAlarm(self._run[0][0], self.suspects, step, size, len(self._run))
            self.reset()
            return alarm
        return None


def locate_step(
    residual_mm: FloatArray,
    design: FloatArray,
    sigma_mm: float,
    prior_mm: float,
    latest: int,
) -> int:
    """Where in a run of tested samples did the sensor move? The row of the first moved one.

    A step is a single time: every sample before it belongs to the old sensor position, every
    one from it on to the new one, whatever the order of the poses (repeated poses too). Each
    split ``k`` in ``0..latest`` is scored by the marginal likelihood of the residuals: the
    rows before it are noise, ``N(0, σ²)``; the rows from it on are noise plus one change of
    the sensor, ``design @ β`` with ``β`` (P0 shift [mm], offset change [mm]) of Gaussian
    prior 1σ ``prior_mm``, so their covariance is ``σ² I + prior_mm² D Dᵀ``. Integrating
    ``β`` out (rather than fitting it) keeps a split with few rows after it from fitting them
    exactly: every split is judged with the same number of parameters, none of them fitted.
    The split of highest likelihood wins; ties go to the latest.

    Parameters
    ----------
    residual_mm : ndarray, shape (m,)
        Measured minus predicted length of the samples since the last one the watch trusts,
        in capture order [mm].
    design : ndarray, shape (m, q)
        How a change of the sensor changes each row's length: ``(−u, 1)`` per row (``u`` the
        unit cable direction from P0 to the hook point) [mm/mm].
    sigma_mm : float
        The residuals' noise, 1σ [mm] (> 0).
    prior_mm : float
        Plausible size of the change, 1σ per component of ``β`` [mm] (> 0).
    latest : int
        The latest possible split (the row of the alarm's first exceeding sample): rows
        from it on are known to be after the move.
    """
    r = np.asarray(residual_mm, dtype=float)
    d = np.asarray(design, dtype=float)
    m = r.shape[0]
    if d.shape[0] != m or not 0 <= latest < m:
        raise ValueError(
            f"residual_mm ({m},), design ({m}, q) and 0 <= latest < {m}: got "
            f"{d.shape} and latest {latest}"
        )
    if not (math.isfinite(sigma_mm) and sigma_mm > 0 and math.isfinite(prior_mm) and prior_mm > 0):
        raise ValueError(f"sigma_mm and prior_mm: finite and > 0, got {sigma_mm}, {prior_mm}")
    var = sigma_mm**2
    best_k, best = latest, -math.inf
    for k in range(latest, -1, -1):
        before = -0.5 * float(r[:k] @ r[:k]) / var - 0.5 * k * math.log(var)
        tail, dt = r[k:], d[k:]
        cov = var * np.eye(m - k) + prior_mm**2 * (dt @ dt.T)
        sign, logdet = np.linalg.slogdet(cov)
        after = -0.5 * float(tail @ np.linalg.solve(cov, tail)) - 0.5 * logdet
        if sign > 0 and before + after > best:
            best_k, best = k, before + after
    return best_k


def next_anchor(current: str, existing: list[str] | tuple[str, ...] = ()) -> str:
    """The anchor id of the session after a move from ``current``: ``A`` → ``A2`` → ``A3``
    (the trailing number counts up), never one in ``existing``."""
    m = re.fullmatch(r"(.*?)(\d+)", current)
    base, k = (m.group(1), int(m.group(2))) if m and m.group(1) else (current, 1)
    taken = set(existing) | {current}
    while True:
        k += 1
        candidate = f"{base}{k}"
        if candidate not in taken:
            return candidate


Kind = Literal["sensor", "robot", "unclear"]


def _lstsq_rss(a: FloatArray, r: FloatArray) -> tuple[float, FloatArray]:
    x: FloatArray = np.asarray(np.linalg.lstsq(a, r, rcond=None)[0], dtype=float)
    rss = float(np.sum((r - a @ x) ** 2))
    return rss, x


def explain_change(
    residual_mm: FloatArray,
    anchor_jac: FloatArray,
    joint_jac: FloatArray,
    noise_mm: float,
    margin: float = 2.0,
) -> dict[str, Any]:
    """Which explains a hold check's residuals better: a moved sensor or a robot change?

    Parameters
    ----------
    residual_mm : ndarray, shape (n,)
        Measured minus predicted lengths at the check poses [mm].
    anchor_jac : ndarray, shape (n, 4)
        ``∂L/∂(P0x, P0y, P0z, c)`` at the check poses [mm/mm]: ``(−u, 1)``.
    joint_jac : ndarray, shape (n, 6)
        ``∂L/∂θj`` for each joint's zero offset [mm/deg].
    noise_mm : float
        Length noise of the calibration [mm] (a floor of the residual variance).
    margin : float
        BIC difference needed to name one explanation.

    Returns
    -------
    dict
        ``kind`` (``sensor``, ``robot`` or ``unclear``), ``anchor_shift_mm`` [3],
        ``offset_change_mm``, ``joint`` (1..6) and ``joint_offset_deg`` of the best robot
        explanation, ``rss_sensor_mm2``, ``rss_robot_mm2``, ``bic_sensor``, ``bic_robot``.
    """
    r = np.asarray(residual_mm, dtype=float)
    a = np.asarray(anchor_jac, dtype=float)
    j = np.asarray(joint_jac, dtype=float)
    n = r.shape[0]
    if a.shape != (n, 4) or j.shape != (n, 6):
        raise ValueError(
            f"anchor_jac (n, 4) and joint_jac (n, 6) for n = {n}: got {a.shape} and {j.shape}"
        )
    rss_s, xs = _lstsq_rss(a, r)
    best = (math.inf, 0, 0.0)
    ones = np.ones((n, 1))
    for k in range(6):
        rss_k, xk = _lstsq_rss(np.hstack([j[:, k : k + 1], ones]), r)
        if rss_k < best[0]:
            best = (rss_k, k, float(xk[0]))
    rss_r, joint, dtheta = best
    floor = n * max(noise_mm, 1e-6) ** 2

    def bic(rss: float, k: int) -> float:
        return float(n * math.log(max(rss, floor) / n) + k * math.log(n))

    rss_c, xc = _lstsq_rss(ones, r)  # a re-zeroed indicator: the offset alone
    b_s, b_r = min(bic(rss_s, 4), bic(rss_c, 1)), bic(rss_r, 2)
    if bic(rss_c, 1) <= bic(rss_s, 4):
        xs = np.array([0.0, 0.0, 0.0, float(xc[0])])
    kind: Kind = "unclear"
    if n >= 6:
        if b_s + margin < b_r:
            kind = "sensor"
        elif b_r + margin < b_s:
            kind = "robot"
    return {
        "kind": kind,
        "anchor_shift_mm": [float(v) for v in xs[:3]],
        "offset_change_mm": float(xs[3]),
        "joint": joint + 1,
        "joint_offset_deg": dtheta,
        "rss_sensor_mm2": rss_s,
        "rss_robot_mm2": rss_r,
        "bic_sensor": b_s,
        "bic_robot": b_r,
    }
