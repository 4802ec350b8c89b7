"""Drift emulation: ``shift_joint_offset`` moves one TRUE joint offset of the emulated cell;
the controller reports the same joint angles while the indicator's length changes by what the
shifted truth model predicts."""

from __future__ import annotations

import time

import numpy as np
import pytest

from calib.models import builtin_model
from calib.synthetic import TABLE_XII_D1, make_true_cell
from drivers import HuashuConfig, HuashuSocketCmdRobot, IndicatorConfig, ModbusIndicator
from simulator.cell import EmulatedCell
from simulator.config import SimConfig
from simulator.runner import SimulatorThread

pytestmark = pytest.mark.anyio

HALF_COUNT_MM = 0.005  # two decimals
DELTA_DEG = 0.05


def predicted_lengths_mm(q_deg: np.ndarray, joint: int, delta_deg: float) -> np.ndarray:
    """Independent prediction: calib's true cell (Table XII D1, default tool, anchor, offset)
    with ``delta_deg`` added to the theta error of ``joint`` (1-based); shape (n,) [mm]."""
    errors = TABLE_XII_D1.copy()
    errors[joint - 1, 3] += delta_deg
    return make_true_cell(builtin_model("hsr-jr680"), dh_errors_deg_mm=errors).lengths_mm(q_deg)


def _hp(endpoint: str | None) -> tuple[str, int]:
    assert endpoint is not None
    host, port = endpoint.rsplit(":", 1)
    return host, int(port)


async def test_shift_joint_offset_changes_lengths_as_the_truth_predicts() -> None:
    cfg = SimConfig(indicator={"baud": 115200, "noise_mm": 0.0})
    q0 = EmulatedCell(cfg).poses_deg[0]
    # The joint whose offset moves the reading at pose 0 most: the test can tell.
    effect = [
        predicted_lengths_mm(q0, j, DELTA_DEG)[0] - predicted_lengths_mm(q0, j, 0.0)[0]
        for j in range(1, 7)
    ]
    joint = int(np.argmax(np.abs(effect))) + 1
    assert abs(effect[joint - 1]) > 0.1  # mm, 20 display counts
    with SimulatorThread(cfg) as sim:
        sim.control("hold", on=True)
        host, port = _hp(sim.ready["robot_socketcmd"])
        robot = HuashuSocketCmdRobot(HuashuConfig(host=host, port=port))
        ind = ModbusIndicator(IndicatorConfig(port=str(sim.ready["indicator_port"]), baud=115200))
        try:
            joints_before = (await robot.read_joints()).joints_deg
            np.testing.assert_allclose(joints_before, q0, atol=1e-6)
            length_before = (await ind.read()).length_mm
            truth_before = sim.control("truth")
            poses = sim.control("poses")["poses_deg"]

            reply = sim.control("shift_joint_offset", joint=joint, delta_deg=DELTA_DEG)

            old = truth_before["joint_offsets_deg"][joint - 1]
            assert reply["joint_offset_deg"] == pytest.approx(old + DELTA_DEG, abs=1e-12)
            truth = sim.control("truth")  # read back: the truth has moved, only there
            assert truth["joint_offsets_deg"][joint - 1] == pytest.approx(old + DELTA_DEG)
            changed = np.flatnonzero(~np.isclose(truth["values"], truth_before["values"]))
            assert truth["names"][int(changed[0])] == f"theta{joint}" and changed.size == 1
            # The controller reports the same angles; the reading follows the new truth.
            joints_after = (await robot.read_joints()).joints_deg
            assert joints_after == pytest.approx(joints_before, abs=1e-9)
            length_after = (await ind.read()).length_mm
            expected = predicted_lengths_mm(q0, joint, DELTA_DEG)[0]
            assert length_after == pytest.approx(expected, abs=HALF_COUNT_MM + 1e-9)
            assert length_after - length_before == pytest.approx(
                effect[joint - 1], abs=2 * HALF_COUNT_MM + 1e-9
            )
            # Every pose: the noise-free lengths are the shifted model's.
            lengths = sim.control("true_lengths", joints_deg=poses)["lengths_mm"]
            np.testing.assert_allclose(
                lengths, predicted_lengths_mm(np.array(poses), joint, DELTA_DEG), atol=1e-9
            )
            # Shifting back restores the original truth.
            sim.control("shift_joint_offset", joint=joint, delta_deg=-DELTA_DEG)
            np.testing.assert_allclose(sim.control("truth")["values"], truth_before["values"])
        finally:
            await robot.close()
            await ind.close()


@pytest.mark.parametrize(
    ("fields", "match"),
    [
        ({"joint": 7, "delta_deg": 0.1}, r"joint: expected 1\.\.6, got 7"),
        ({"joint": "2", "delta_deg": 0.1}, "joint: expected an integer"),
        ({"joint": 2, "delta_deg": float("nan")}, "delta_deg: not finite"),
        ({"joint": 2}, "delta_deg"),
    ],
)
def test_shift_joint_offset_rejects_bad_input(fields: dict[str, object], match: str) -> None:
    with SimulatorThread(SimConfig(indicator={"pty": False})) as sim:
        before = sim.control("truth")["values"]
        with pytest.raises(RuntimeError, match=match):
            sim.control("shift_joint_offset", **fields)
        assert sim.control("truth")["values"] == before


def test_move_anchor_and_drift_offset_follow_the_truth() -> None:
    """``move_anchor`` moves the true P0 (lengths follow |p - P0'| + c); ``drift_offset``
    adds a linear or first-order drift to every reading; ``truth`` reports both."""
    cfg = SimConfig(indicator={"pty": False, "noise_mm": 0.0})
    with SimulatorThread(cfg) as sim:
        poses = np.array(sim.control("poses")["poses_deg"][:5])
        before = np.array(sim.control("true_lengths", joints_deg=poses.tolist())["lengths_mm"])
        reply = sim.control("move_anchor", delta_mm=[4, 0, -2])
        assert reply["anchor_p0_mm"] == pytest.approx([1404.0, 300.0, 198.0])
        assert reply["truth"]["anchor_p0_mm"] == pytest.approx([1404.0, 300.0, 198.0])
        moved = np.array(sim.control("true_lengths", joints_deg=poses.tolist())["lengths_mm"])
        # Independent prediction: calib's true cell with the moved anchor.
        expected = make_true_cell(
            builtin_model("hsr-jr680"), anchors_mm=np.array([[1404.0, 300.0, 198.0]])
        ).lengths_mm(poses)
        np.testing.assert_allclose(moved, expected, atol=1e-9)
        assert np.abs(moved - before).max() > 1.0  # the bump is visible

        sim.control("drift_offset", rate_mm_per_h=3600.0)  # 1 mm/s: measurable in a test
        t0 = sim.control("truth")["drift"]["drift_mm"]
        sim.control("hold", on=True)
        time.sleep(0.3)
        truth = sim.control("truth")
        assert truth["drift"]["rate_mm_per_h"] == 3600.0
        assert 0.25 < truth["drift"]["drift_mm"] - t0 < 1.0
        assert truth["offset_mm"] == pytest.approx(-350.0 + truth["drift"]["drift_mm"], abs=0.05)
        # A first-order drift saturates at rate * tau: 1 mm/s * 0.05 s = 0.05 mm more.
        kept = sim.control("drift_offset", rate_mm_per_h=3600.0, tau_s=0.05)["truth"]
        time.sleep(0.4)
        settled = sim.control("truth")["drift"]["drift_mm"]
        assert settled - kept["drift"]["drift_mm"] == pytest.approx(0.05, abs=0.002)


def test_cell_drift_from_the_config_is_linear_in_time() -> None:
    from simulator.cell import OffsetDrift

    cfg = SimConfig(cell={"drift_rate_mm_per_h": 2.0})
    cell = EmulatedCell(cfg)
    assert cell.drift == OffsetDrift(2.0, 0.0, cell.drift.t0)
    assert cell.drift_mm(cell.drift.t0 + 1800.0) == pytest.approx(1.0)
    q = cell.poses_deg[:1]
    base = cell.truth.lengths_mm(q)[0]
    assert cell.true_lengths_mm(q, cell.drift.t0 + 3600.0)[0] == pytest.approx(base + 2.0)
    with pytest.raises(ValueError, match="drift_rate_mm_per_h"):
        SimConfig(cell={"drift_rate_mm_per_h": float("nan")})


@pytest.mark.parametrize(
    ("cmd", "fields", "match"),
    [
        ("move_anchor", {"delta_mm": [4, 0]}, "delta_mm: expected a list of 3"),
        ("move_anchor", {}, "delta_mm: expected a list of 3"),
        ("move_anchor", {"delta_mm": [4, "x", 0]}, r"delta_mm\[1\]: expected a number"),
        ("move_anchor", {"delta_mm": [4, 0, 1e9]}, r"delta_mm\[2\]: .* outside"),
        ("drift_offset", {}, "rate_mm_per_h: required"),
        ("drift_offset", {"rate_mm_per_h": True}, "rate_mm_per_h: expected a number"),
        ("drift_offset", {"rate_mm_per_h": 1.0, "tau_s": -1}, "tau_s: .* outside"),
        ("drift_offset", {"rate_mm_per_h": 1e6}, "rate_mm_per_h: .* outside"),
    ],
)
def test_disturbances_reject_bad_input(cmd: str, fields: dict[str, object], match: str) -> None:
    with SimulatorThread(SimConfig(indicator={"pty": False})) as sim:
        before = sim.control("truth")
        with pytest.raises(RuntimeError, match=match):
            sim.control(cmd, **fields)
        after = sim.control("truth")
        assert after["values"] == before["values"] and after["drift"] == before["drift"]
