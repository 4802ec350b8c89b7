"""Helpers of the brand-face tests (KUKA VarProxy, FANUC RMI): how far a joint reading is
from the emulated cell's truth."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from simulator.runner import SimulatorThread


def deviation_from_truth_deg(
    sim: SimulatorThread, joints_deg: Sequence[float], t_from_s: float, t_to_s: float
) -> float:
    """``min_t max_j |q_j(t) - reading_j|`` [deg] for t in [t_from_s, t_to_s] (monotonic
    seconds): how far a reading is from the cell's truth at any instant of that span (0.5 ms
    grid, then 0.01 ms around the best instant)."""
    reading = np.asarray(joints_deg, dtype=float)

    def best(times_s: np.ndarray) -> tuple[float, float]:
        devs = [float(np.abs(sim.cell.reported_joints(t) - reading).max()) for t in times_s]
        k = int(np.argmin(devs))
        return float(times_s[k]), devs[k]

    t_best, _ = best(np.arange(t_from_s - 0.001, t_to_s + 0.0005, 0.0005))
    return best(np.arange(t_best - 0.0006, t_best + 0.0006, 0.00001))[1]


def last_tx_s(frames: Sequence[str]) -> float:
    """Monotonic time [s] of the last frame sent, from a driver's frame log."""
    return max(float(line.split()[0]) for line in frames if " tx " in line)
