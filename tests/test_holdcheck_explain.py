"""A hold check names its likely cause: a moved sensor (a point shift of P0) changes the
check poses' lengths differently from a robot change (a joint's zero offset). Known truth:
the EMULATED cell, calibrated on its own samples, then disturbed one way or the other."""

from __future__ import annotations

import numpy as np
import pytest

from calib.dataset import SampleSet
from calib.identify import IdentifyOptions, identify
from calib.monitor.holdcheck import evaluate, spread_indices
from simulator.cell import EmulatedCell
from simulator.config import SimConfig

NOISE_MM = 0.02


def _samples(q: np.ndarray, lengths: np.ndarray) -> SampleSet:
    n = len(lengths)
    return SampleSet(
        joints_deg=q, length_mm=lengths, anchor=("A",) * n, group=None, line=np.arange(2, n + 2)
    )


@pytest.fixture(scope="module")
def calibrated() -> tuple[EmulatedCell, dict[str, object], np.ndarray]:
    cell = EmulatedCell(SimConfig(seed=3, robot={"n_poses": 60}))
    q = cell.poses_deg
    rng = np.random.default_rng(0)
    lengths = cell.truth.lengths_mm(q) + rng.normal(0.0, NOISE_MM, len(q))
    result = identify(cell.truth.model, _samples(q, lengths), IdentifyOptions()).to_json()
    return cell, result, q[spread_indices(q, 8)]


@pytest.mark.parametrize(
    ("disturb", "kind", "joint"),
    [
        (lambda c: c.move_anchor([3.0, -2.0, 1.5]), "sensor", None),
        (lambda c: c.set_display_mm(c.true_length_mm() + 1.0), "sensor", None),  # re-zeroed
        (lambda c: c.shift_joint_offset(2, 0.05), "robot", 2),
        (lambda c: c.shift_joint_offset(3, -0.05), "robot", 3),
    ],
    ids=["anchor-shift", "re-zero", "joint2", "joint3"],
)
def test_a_hold_check_names_robot_or_sensor(
    calibrated: tuple[EmulatedCell, dict[str, object], np.ndarray],
    disturb: object,
    kind: str,
    joint: int | None,
) -> None:
    base, result, check_q = calibrated
    cell = EmulatedCell(base.config)
    disturb(cell)  # type: ignore[operator]
    rng = np.random.default_rng(1)
    lengths = cell.truth.lengths_mm(check_q) + rng.normal(0.0, NOISE_MM, len(check_q))
    ev = evaluate(dict(result), _samples(check_q, lengths), limit_mm=0.1, refit_anchor=False)
    assert ev.status == "not_held"
    explained = ev.detail["explanation"]
    assert explained["kind"] == kind, explained
    if joint is not None:
        assert explained["joint"] == joint
        assert abs(explained["joint_offset_deg"]) == pytest.approx(0.05, abs=0.02)
