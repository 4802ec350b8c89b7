"""Our drivers read the emulated cell over a real pty and over loopback TCP; readings match
the cell's truth within quantisation (and noise, where noise is on)."""

from __future__ import annotations

import asyncio
import math
import time

import numpy as np
import pytest
from helpers import host_port, start_emulated_cell

from drivers import (
    AsciiIndicator,
    AsciiIndicatorConfig,
    HuashuConfig,
    HuashuSocketCmdRobot,
    IndicatorConfig,
    ModbusIndicator,
    ModbusRobotConfig,
    ModbusTcpRobot,
    RobotStale,
)
from simulator.runner import SimulatorThread

pytestmark = [
    pytest.mark.anyio,
    pytest.mark.emulated_cell(indicator={"baud": 115200, "noise_mm": 0.0, "tcp": "rtu"}),
]
HALF_COUNT_MM = 0.005  # two decimals


async def test_indicator_over_pty_matches_truth_at_every_pose(sim: SimulatorThread) -> None:
    port = sim.ready["indicator_port"]
    assert port is not None
    ind = ModbusIndicator(IndicatorConfig(port=port, baud=115200))
    try:
        sim.control("hold", on=True)
        poses = sim.control("poses")["poses_deg"][:5]
        truths = sim.control("true_lengths", joints_deg=poses)["lengths_mm"]
        state = sim.control("state")
        reading = await ind.read()
        assert abs(reading.length_mm - state["true_length_mm"]) <= HALF_COUNT_MM + 1e-9
        assert state["true_length_mm"] == pytest.approx(truths[0], abs=1e-9)
        assert not reading.moving and not reading.over_range and reading.decimals == 2
        # The reading follows the robot: lengths differ between poses, as the truth does.
        assert len({round(t, 1) for t in truths}) == len(truths)
    finally:
        await ind.close()


async def test_indicator_noise_is_seeded_and_within_sigma() -> None:
    s = start_emulated_cell(indicator={"baud": 115200, "noise_mm": 0.05, "update_hz": 200.0})
    ind = ModbusIndicator(IndicatorConfig(port=str(s.ready["indicator_port"]), baud=115200))
    try:
        true = s.control("state")["true_length_mm"]  # at pose 0 for the first dwell
        values = []
        for _ in range(40):
            values.append((await ind.read()).length_mm)
            await asyncio.sleep(0.006)
        err = np.array(values) - true
        assert np.std(err) == pytest.approx(0.05, rel=0.5)
        assert np.max(np.abs(err)) < 5 * 0.05 + HALF_COUNT_MM
        assert len(set(values)) > 3  # noise is really there
    finally:
        await ind.close()
        s.stop()


async def test_indicator_rtu_over_tcp_and_modbus_tcp(sim: SimulatorThread) -> None:
    sim.control("hold", on=True)
    true = sim.control("state")["true_length_mm"]
    host, tcp_port = host_port(sim.ready["indicator_tcp"])
    ind = ModbusIndicator(IndicatorConfig(port=f"socket://{host}:{tcp_port}", timeout_s=1.0))
    try:
        assert abs((await ind.read()).length_mm - true) <= HALF_COUNT_MM + 1e-9
    finally:
        await ind.close()
    s2 = start_emulated_cell(indicator={"noise_mm": 0.0, "tcp": "mbap", "pty": False})
    try:
        assert s2.ready["indicator_port"] is None
        s2.control("hold", on=True)
        true2 = s2.control("state")["true_length_mm"]
        host, tcp_port = host_port(s2.ready["indicator_tcp"])
        ind2 = ModbusIndicator(IndicatorConfig(kind="modbus-tcp", host=host, tcp_port=tcp_port))
        try:
            assert abs((await ind2.read()).length_mm - true2) <= HALF_COUNT_MM + 1e-9
        finally:
            await ind2.close()
    finally:
        s2.stop()


async def test_zero_command_changes_the_cells_offset(sim: SimulatorThread) -> None:
    sim.control("hold", on=True)
    before = sim.control("truth")
    length = sim.control("state")["true_length_mm"]
    ind = ModbusIndicator(IndicatorConfig(port=str(sim.ready["indicator_port"]), baud=115200))
    try:
        await ind.zero()
        assert abs((await ind.read()).length_mm) <= HALF_COUNT_MM
    finally:
        await ind.close()
    after = sim.control("truth")
    assert after["offset_mm"] == pytest.approx(before["offset_mm"] - length, abs=1e-9)


async def test_moving_bit_follows_the_robot() -> None:
    s = start_emulated_cell(
        indicator={"baud": 115200, "noise_mm": 0.0},
        robot={"move_time_s": 0.4, "dwell_s": 0.3},
    )
    # Between poses the interpolated path may leave the cable range: flag, don't raise.
    cfg = IndicatorConfig(
        port=str(s.ready["indicator_port"]), baud=115200, over_range_policy="flag"
    )
    ind = ModbusIndicator(cfg)
    try:
        flags, lengths = set(), []
        t_end = time.monotonic() + 1.2
        while time.monotonic() < t_end:
            r = await ind.read()
            flags.add(r.moving)
            lengths.append(r.length_mm)
        assert flags == {True, False}
        assert max(lengths) - min(lengths) > 1.0  # the cable length changed while moving
    finally:
        await ind.close()
        s.stop()


async def test_over_range_flag_from_the_cell() -> None:
    s = start_emulated_cell(indicator={"baud": 115200, "range_mm": [0.0, 100.0]})
    ind = ModbusIndicator(
        IndicatorConfig(port=str(s.ready["indicator_port"]), baud=115200, over_range_policy="flag")
    )
    try:
        r = await ind.read()
        assert r.over_range and r.length_mm == pytest.approx(100.0)
    finally:
        await ind.close()
        s.stop()


async def test_huashu_driver_reads_emulated_controller(sim: SimulatorThread) -> None:
    sim.control("hold", on=True)
    state = sim.control("state")
    host, port = host_port(sim.ready["robot_socketcmd"])
    robot = HuashuSocketCmdRobot(HuashuConfig(host=host, port=port))
    try:
        reading = await robot.read_joints()
        assert reading.joints_deg == pytest.approx(state["joints_deg"], abs=1e-6)
        loc = await robot.read_location()
        xyz = sim.cell.truth.tool_positions_mm(np.array(state["joints_deg"]))[0]
        assert loc[:3] == pytest.approx(list(xyz), abs=1e-5)
        sim.control("alarm", code=1003, text="emulated servo alarm")
        await robot.read_joints()  # the alarm arrives before or with this reply
        await asyncio.sleep(0.05)
        await robot.read_joints()
        assert [a.code for a in robot.alarms] == [1003]
        with pytest.raises(Exception, match="controller error 1"):
            await robot.command("mot.unknown()")
    finally:
        await robot.close()


async def test_ur_modbus_driver_reads_emulated_controller(sim: SimulatorThread) -> None:
    sim.control("hold", on=True)
    state = sim.control("state")
    host, port = host_port(sim.ready["robot_modbus"])
    robot = ModbusTcpRobot(ModbusRobotConfig(host=host, port=port))
    try:
        reading = await robot.read_joints()
    finally:
        await robot.close()
    # 1 mrad register resolution: half a step is 0.0287 deg.
    assert reading.joints_deg == pytest.approx(state["joints_deg"], abs=math.degrees(0.0005) + 1e-9)
    assert any(q < 0 for q in state["joints_deg"])  # the negative-turn path is exercised


async def test_frozen_controller_is_caught_by_the_stale_guard() -> None:
    s = start_emulated_cell(
        robot={"move_time_s": 0.3, "dwell_s": 0.0}, faults={"robot_frozen": True}
    )
    host, port = host_port(s.ready["robot_socketcmd"])
    robot = HuashuSocketCmdRobot(HuashuConfig(host=host, port=port, max_unchanged_s=0.2))
    try:
        first = await robot.read_joints()
        await asyncio.sleep(0.3)
        state = s.control("state")
        assert state["moving"] and state["joints_deg"] != pytest.approx(first.joints_deg)
        with pytest.raises(RobotStale):
            await robot.read_joints()
        s.control("fault", robot_frozen=False)
        await asyncio.sleep(0.05)
        fresh = await robot.read_joints()
        assert fresh.joints_deg != first.joints_deg
    finally:
        await robot.close()
        s.stop()


async def test_ascii_stream_indicator() -> None:
    s = start_emulated_cell(
        indicator={"mode": "ascii", "noise_mm": 0.0, "baud": 115200, "ascii_rate_hz": 50}
    )
    s.control("hold", on=True)
    true = s.control("state")["true_length_mm"]
    ind = AsciiIndicator(AsciiIndicatorConfig(port=str(s.ready["indicator_port"]), baud=115200))
    try:
        readings = [await ind.read() for _ in range(3)]
    finally:
        await ind.close()
        s.stop()
    for r in readings:
        assert abs(r.length_mm - true) <= HALF_COUNT_MM + 1e-9
