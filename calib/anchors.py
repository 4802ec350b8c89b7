"""Locating the anchors: every anchor's ``P0`` and zero offset ``c`` fitted to the samples
under given kinematics (:func:`fit_anchors`), and the plain least-squares fit it and
identify's internal fits share (:func:`plain_fit`).

Here and not in :mod:`calib.cable` because the fit needs :class:`calib.problem.Problem`,
which itself builds on :mod:`calib.cable` (that would be an import cycle).
"""

from __future__ import annotations

import numpy as np

from calib.cable import MIN_ANCHOR_SAMPLES, N_KIN, ParamLayout, kinematic_parts, multilaterate
from calib.dataset import SampleError
from calib.kinematics import FloatArray, forward_position
from calib.models import RobotModel
from calib.problem import Problem
from calib.solvers import geolm

#: The plain fits' solver options (:func:`plain_fit`, :func:`calib.drift.select_at_plain_fit`).
PLAIN_FIT = geolm.GeoLMOptions(max_iterations=100)


def plain_fit(problem: Problem, x0: FloatArray | None = None) -> FloatArray:
    """The full vector at the least-squares optimum of ``problem`` from ``x0`` (k,), by
    geodesic LM: its tiny initial damping and the acceleration meet LM's stopping tests in
    fewer iterations than LM (bench/cli_speed.md times the whole identify)."""
    res = geolm.descend(problem, problem.x0() if x0 is None else x0, PLAIN_FIT)
    return problem.full(res.x)


def fit_anchors(
    model: RobotModel,
    layout: ParamLayout,
    theta: FloatArray,
    q_rad: FloatArray,
    anchor_index: np.ndarray,
    length_mm: FloatArray,
) -> FloatArray:
    """``theta`` with every anchor's P0 and c fitted (multilateration start, LM refinement)."""
    theta = theta.copy()
    dh, tool = kinematic_parts(model, theta)
    pts = forward_position(dh, q_rad, tool, model.convention)
    for k in range(len(layout.anchors)):
        rows = anchor_index == k
        if np.count_nonzero(rows) < MIN_ANCHOR_SAMPLES:
            raise SampleError(
                f"anchor {layout.anchors[k]!r} has {np.count_nonzero(rows)} samples; at least "
                f"{MIN_ANCHOR_SAMPLES} are needed to locate it",
                column="anchor",
            )
        p0, c = multilaterate(pts[rows], length_mm[rows])
        if not (np.all(np.isfinite(p0)) and np.isfinite(c)):
            p0, c = pts[rows].mean(axis=0) + 500.0, 0.0
        theta[layout.anchor_slice(k)] = [*p0, c]
    free = np.zeros(layout.size, dtype=bool)
    free[N_KIN:] = True
    prob = Problem(model, layout, q_rad, length_mm, anchor_index, free, theta)
    return plain_fit(prob)
