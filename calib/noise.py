"""What the data can say about their own noise: the display step, its floor, the dof correction.

The noise estimate of an identification (:func:`calib.prior.noise_from_map`) and the scale of
the outlier screening (:mod:`calib.robust`) both come from the fit's residuals. Two facts
bound what they can mean:

- the indicator shows the length to a display step ``q`` (0.01 mm with two decimals): the
  rounding alone has a standard deviation of ``q / sqrt(12)``, so no noise estimate below
  that is real. The step is read from the data (:func:`display_step_mm`: the coarsest
  decimal step every length is a multiple of), not assumed;
- with ``ν`` degrees of freedom left after the fit (the redundancy, prior included),
  ``Σ r² / ν`` is unbiased for ``σ²`` but below it more often than not when ``ν`` is small
  (60 % of the time at ``ν = 2``): its median is ``σ² · m(ν) / ν`` with ``m(ν)`` the median of
  χ²(ν). :func:`median_dof` returns ``m(ν)``; dividing by it gives an estimate that is as
  often above the truth as below at every ``ν``, and the same as dividing by ``ν`` once ``ν``
  is large (``m(ν) ≈ ν − 2/3``).

Imports only numpy.
"""

from __future__ import annotations

import math

import numpy as np

from calib.kinematics import FloatArray

#: Decimal places tried by :func:`display_step_mm` (steps 1, 0.1, …, 0.0001 mm).
MAX_DECIMALS = 4
#: A length is "on the step" when within this share of the step of a multiple of it.
STEP_TOLERANCE = 1e-4


def display_step_mm(length_mm: FloatArray) -> float | None:
    """The coarsest decimal step [mm] (1, 0.1, …, 10**-MAX_DECIMALS) every finite length of
    ``length_mm`` (shape (n,)) is a multiple of, or None when they have more decimals (not
    quantised, e.g. averaged readings) or there are fewer than two lengths."""
    values = np.asarray(length_mm, dtype=float)
    values = values[np.isfinite(values)]
    if values.size < 2:
        return None
    for decimals in range(MAX_DECIMALS + 1):
        step = 10.0**-decimals
        scaled = values / step
        if np.all(np.abs(scaled - np.round(scaled)) < STEP_TOLERANCE):
            return step
    return None


def noise_floor_mm(length_mm: FloatArray) -> float:
    """The smallest noise [mm] the lengths (shape (n,)) can show: ``step / sqrt(12)`` of their
    display step (:func:`display_step_mm`), 0 when they are not quantised."""
    step = display_step_mm(length_mm)
    return 0.0 if step is None else step / math.sqrt(12.0)


def median_dof(dof: float) -> float:
    """The median of χ² with ``dof`` (>= 1, not necessarily whole) degrees of freedom, by the
    Wilson–Hilferty approximation ``dof · (1 − 2/(9 dof))³``: 3.4 % above the exact median at
    1 degree of freedom, 1.3 % at 2, under 0.1 % from 10 (numpy only: importing scipy.special
    would be a cost of every identify's start, bench/cli_speed.md)."""
    return float(dof * (1.0 - 2.0 / (9.0 * dof)) ** 3)
