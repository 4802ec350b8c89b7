"""The live watch's per-sample test (:class:`calib.monitor.running_fit.LiveTester`) on known
truth: the EMULATED cell's lengths, sample by sample, as the daemon feeds them."""

from __future__ import annotations

import numpy as np
import pytest

from calib.dataset import SampleSet
from calib.monitor.running_fit import LiveTester
from calib.monitor.stepwatch import StepDetector
from simulator.cell import EmulatedCell
from simulator.config import SimConfig


def _replay(cell: EmulatedCell, lengths: np.ndarray) -> tuple[list[tuple[int, object]], list[str]]:
    q = cell.poses_deg[: len(lengths)]
    tester = LiveTester(cell.truth.model, None, StepDetector())
    alarms, kinds = [], []
    for i in range(len(lengths)):
        ids = list(range(i + 1))
        clean = tester.clean_rows(ids, i)
        if tester.needs_refit(len(clean)):
            rows = np.array(clean, dtype=int)
            sub = SampleSet(joints_deg=q[rows], length_mm=lengths[rows],
                            anchor=("A",) * len(rows), group=None, line=rows + 2)  # fmt: skip
            tester.refit(sub, len(clean), [int(r) for r in rows])
        _, alarm = tester.test(i, q[i], float(lengths[i]), "A")
        kinds.append(tester.fit.kind if tester.fit else "none")
        if alarm is not None:
            alarms.append((i, alarm))
            break
    return alarms, kinds


@pytest.mark.slow  # about 4 s: the look back fits ~20 splits
def test_a_bump_before_any_fit_could_test_is_found_by_the_look_back() -> None:
    cell = EmulatedCell(SimConfig(seed=11, robot={"n_poses": 40}))
    q = cell.poses_deg
    rng = np.random.default_rng(2)
    clean = cell.truth.lengths_mm(q)
    cell.move_anchor([4.0, 0.0, 0.0])
    lengths = np.concatenate([clean[:12], cell.truth.lengths_mm(q[12:])])
    lengths += rng.normal(0.0, 0.02, len(lengths))
    alarms, kinds = _replay(cell, lengths)
    assert kinds[10] == "nominal"  # the nominal model is not tested: no alarm there
    assert len(alarms) == 1
    at, alarm = alarms[0]
    assert alarm.first_key == 12  # placed at the bump
    assert alarm.keys == tuple(range(12, at + 1))
    assert 2.0 < alarm.step_mm < 4.5  # 4 mm along x lengthens these poses' cable


def test_a_clean_campaign_raises_no_alarm_and_reaches_the_identify_fit() -> None:
    cell = EmulatedCell(SimConfig(seed=12, robot={"n_poses": 40}))
    lengths = cell.truth.lengths_mm(cell.poses_deg)
    lengths += np.random.default_rng(3).normal(0.0, 0.02, len(lengths))
    alarms, kinds = _replay(cell, lengths)
    assert alarms == []
    assert kinds[-1] == "identify"
