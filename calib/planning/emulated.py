"""Planned against random poses on EMULATED cells: the measured accuracy of a plan.

One trial (:func:`emulated_trial`) builds a virtual cell with known truth
(:func:`calib.synthetic.make_true_cell`: the paper's Table XII DH errors, tool error
(0.8, −0.5, 1.2) mm, the sensor at (1400, 300, 200) mm), guesses the anchor
``anchor_error_mm`` off in a seeded random direction, plans ``n`` poses at the guess, draws
``random_designs`` sets of ``n`` random poses from the same feasible set (joint limits, cable
stroke shrunk by the anchor uncertainty, floor: :func:`calib.planning.candidates.draw_candidates`
with the plan's own options), simulates noisy lengths for each, fits each with ``identify``
(its defaults, method LM, no hold-out) and measures the fitted model's aligned TCP RMS error
against the truth at ``workspace_poses`` held-out workspace poses. Averaging several random
designs per seed estimates the random baseline's expectation with less spread than one draw.

Used by ``tests/test_planning.py`` and ``bench/plan_bench.py``; nothing here touches a real
cell.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from calib.cable import kinematic_parts
from calib.dataset import make_samples
from calib.identify import IdentifyOptions, identify
from calib.kinematics import FloatArray, forward_position
from calib.models import RobotModel
from calib.planning.candidates import draw_candidates
from calib.planning.options import PlanOptions
from calib.planning.planner import plan
from calib.synthetic import make_true_cell, noisy_lengths
from calib.tcp import aligned_position_error_mm, workspace_sample_deg

#: The true anchor of the emulated cell [mm] (``make_true_cell``'s default).
TRUE_ANCHOR_MM = np.array([1400.0, 300.0, 200.0])


@dataclass(frozen=True)
class Trial:
    """Aligned TCP RMS errors [mm] of one emulated trial, measured and predicted."""

    seed: int
    planned_mm: float
    random_mm: tuple[float, ...]
    predicted_planned_mm: float
    predicted_random_mm: float

    @property
    def random_mean_mm(self) -> float:
        return float(np.mean(self.random_mm))


def anchor_guess_mm(seed: int, error_mm: float = 30.0) -> FloatArray:
    """The true anchor moved ``error_mm`` in a seeded random direction, shape (3,) [mm]."""
    step = np.random.default_rng(100 + seed).normal(size=3)
    out: FloatArray = TRUE_ANCHOR_MM + error_mm * step / np.linalg.norm(step)
    return out


def emulated_trial(
    model: RobotModel,
    seed: int,
    options: PlanOptions | None = None,
    *,
    noise_mm: float = 0.05,
    anchor_error_mm: float = 30.0,
    random_designs: int = 3,
    workspace_poses: int = 500,
) -> Trial:
    """Plan at a guessed anchor, fit planned and random poses, measure against the truth.

    ``options`` default ``PlanOptions(n=40, seed=seed)``; their ``n``, stroke, floor and
    anchor uncertainty also bound the random poses. Noise, random draws and the workspace
    sample are seeded by ``seed``.
    """
    opts = options or PlanOptions(n=40, seed=seed)
    cell = make_true_cell(model, offsets_mm=np.array([-20.0]))
    rng = np.random.default_rng(seed)
    guess = anchor_guess_mm(seed, anchor_error_mm)
    res = plan(model, guess, opts)
    ws = workspace_sample_deg(model, workspace_poses, seed=1000 + seed, min_z_mm=opts.min_z_mm)
    p_true = cell.tool_positions_mm(ws)
    fit_opts = IdentifyOptions(method="lm", test_fraction=0.0)

    def error_mm(q_deg: FloatArray) -> float:
        samples = make_samples(q_deg, noisy_lengths(cell, q_deg, rng, noise_mm=noise_mm))
        dh, tool = kinematic_parts(model, identify(model, samples, fit_opts).theta)
        p_fit = forward_position(dh, model.table_rad(ws), tool, model.convention)
        return float(np.sqrt(np.mean(aligned_position_error_mm(p_fit, p_true) ** 2)))

    planned = error_mm(res.q_deg)
    random_ = []
    for _ in range(random_designs):
        q_rand, _ = draw_candidates(
            model,
            guess[None],
            opts.n,
            rng,
            opts.extension_mm,
            opts.min_z_mm,
            opts.anchor_uncertainty_mm,
        )
        random_.append(error_mm(q_rand))
    return Trial(seed, planned, tuple(random_), res.tcp.rms_mm, res.tcp_random["rms"])


def ratio_of_means(trials: list[Trial]) -> float:
    """Mean planned error over mean random error (random: each trial's mean over designs)."""
    return float(
        np.mean([t.planned_mm for t in trials]) / np.mean([t.random_mean_mm for t in trials])
    )
