"""The default emulated cell (``make run``): 60 distinct, spread poses within the joint limits,
the sensor's stroke and above the floor; free TCP ports by default, reported once bound, and
fixed ports still possible."""

from __future__ import annotations

import socket
from pathlib import Path

import numpy as np
import pytest

from drivers import HuashuConfig, HuashuSocketCmdRobot, ModbusRobotConfig, ModbusTcpRobot
from simulator.cell import EmulatedCell
from simulator.config import SimConfig, load_config, with_ports
from simulator.faces import FACES
from simulator.poses import flange_and_hook_z_mm
from simulator.runner import SimulatorThread

pytestmark = pytest.mark.anyio

ROOT = Path(__file__).resolve().parents[1]
#: The identification's minimum sample count (``cablecal identify``).
MIN_SAMPLES = 30
#: The sensor's stroke [mm] (HY150-2000) minus the 50 mm margins.
STROKE_MM = (50.0, 1950.0)


@pytest.mark.parametrize("source", ["defaults", "examples/sim.toml"])
def test_default_cell_has_60_distinct_poses_within_limits_stroke_and_floor(source: str) -> None:
    cfg = SimConfig() if source == "defaults" else load_config(ROOT / "examples" / "sim.toml")
    cell = EmulatedCell(cfg)
    q = cell.poses_deg
    assert q.shape == (60, 6) and q.shape[0] >= 2 * MIN_SAMPLES
    limits = cell.truth.model.limits_deg()
    assert np.all((q >= limits[:, 0]) & (q <= limits[:, 1]))
    extension = np.linalg.norm(cell.truth.tool_positions_mm(q) - cell.anchor_mm, axis=1)
    assert np.all((extension > STROKE_MM[0]) & (extension < STROKE_MM[1]))
    reading = cell.truth.lengths_mm(q)
    lo, hi = cfg.indicator.range_mm
    assert np.all((reading > lo + 50.0) & (reading < hi - 50.0))  # never over/under range
    flange_z, hook_z = flange_and_hook_z_mm(cell.truth, q)
    assert np.all(flange_z >= cfg.robot.min_z_mm) and np.all(hook_z >= cfg.robot.min_z_mm)
    # Distinct for the sampler (auto capture skips poses within a few degrees of a known one)
    # and spread: every pair differs by more than 10 deg in some joint.
    diff = np.abs(q[:, None, :] - q[None, :, :]).max(axis=2) + np.eye(60) * 1e9
    assert diff.min() > 10.0
    # Variety: every joint uses most of its range (wrists are kept within +-170 deg).
    usable_deg = np.minimum(limits[:, 1] - limits[:, 0], 340.0)
    span = (q.max(axis=0) - q.min(axis=0)) / usable_deg
    assert np.all(span > 0.8), span


def test_default_poses_are_seeded_and_respect_a_raised_floor() -> None:
    a, b = EmulatedCell(SimConfig()), EmulatedCell(SimConfig())
    np.testing.assert_array_equal(a.poses_deg, b.poses_deg)
    assert not np.allclose(EmulatedCell(SimConfig(seed=1)).poses_deg, a.poses_deg)
    high = EmulatedCell(SimConfig.model_validate({"robot": {"min_z_mm": 600.0, "n_poses": 30}}))
    flange_z, hook_z = flange_and_hook_z_mm(high.truth, high.poses_deg)
    assert flange_z.min() >= 600.0 and hook_z.min() >= 600.0
    assert flange_and_hook_z_mm(a.truth, a.poses_deg)[0].min() < 600.0  # the floor mattered
    with pytest.raises(ValueError, match=r"above z = 5000.0 mm"):
        EmulatedCell(SimConfig.model_validate({"robot": {"min_z_mm": 5000.0}}))


def _hp(endpoint: str | None) -> tuple[str, int]:
    assert endpoint is not None
    host, port = endpoint.rsplit(":", 1)
    return host, int(port)


async def test_free_ports_by_default_and_two_cells_at_once() -> None:
    one = SimulatorThread(SimConfig(seed=1, indicator={"pty": False})).start()
    try:
        two = SimulatorThread(SimConfig(seed=2, indicator={"pty": False})).start()
        try:
            ports = [one.ports, two.ports]
            faces = {face.ready_key for face in FACES.values()}
            for sim, p in zip((one, two), ports, strict=True):
                assert set(p) == {"robot_socketcmd", "robot_modbus", "control", *faces}
                assert all(v > 0 for v in p.values())
                assert p["robot_socketcmd"] == _hp(sim.ready["robot_socketcmd"])[1]
            # No endpoint shared (the UR faces share port 30004 on distinct loopback hosts).
            endpoints = [
                {v for k, v in sim.ready.items() if k != "indicator_port"} for sim in (one, two)
            ]
            assert not (endpoints[0] & endpoints[1]) - {None}
            for sim in (one, two):  # each driver reads its own cell
                sim.control("hold", on=True)
                state = sim.control("state")
                host, port = _hp(sim.ready["robot_socketcmd"])
                hs = HuashuSocketCmdRobot(HuashuConfig(host=host, port=port))
                host, port = _hp(sim.ready["robot_modbus"])
                ur = ModbusTcpRobot(ModbusRobotConfig(host=host, port=port))
                try:
                    assert (await hs.read_joints()).joints_deg == pytest.approx(
                        state["joints_deg"], abs=1e-6
                    )
                    assert (await ur.read_joints()).joints_deg == pytest.approx(
                        state["joints_deg"], abs=0.03
                    )
                finally:
                    await hs.close()
                    await ur.close()
            assert one.control("state")["joints_deg"] != two.control("state")["joints_deg"]
        finally:
            two.stop()
    finally:
        one.stop()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_fixed_ports_are_honoured() -> None:
    want = {"robot_socketcmd": _free_port(), "robot_modbus": _free_port()}
    cfg = SimConfig.model_validate(
        {key: {"port": port} for key, port in want.items()} | {"indicator": {"pty": False}}
    )
    with SimulatorThread(cfg) as sim:
        assert sim.ports["robot_socketcmd"] == want["robot_socketcmd"]
        assert sim.ports["robot_modbus"] == want["robot_modbus"]
        assert sim.ready["robot_socketcmd"] == f"127.0.0.1:{want['robot_socketcmd']}"


def test_with_ports_overrides_and_validates() -> None:
    cfg = with_ports(SimConfig(), robot_socketcmd=23333, robot_modbus=None, control=0)
    assert (cfg.robot_socketcmd.port, cfg.robot_modbus.port, cfg.control.port) == (23333, 0, 0)
    assert cfg.indicator == SimConfig().indicator  # everything else kept
    with pytest.raises(ValueError, match="unknown server 'indicator'"):
        with_ports(SimConfig(), indicator=1)
    with pytest.raises(ValueError, match="less than or equal to 65535"):
        with_ports(SimConfig(), control=70000)


def test_faces_and_drivers_state_the_controllers_defaults_apart_but_alike() -> None:
    """The emulated faces keep their own copy of a real controller's facts (ABB's factory
    login, UR's RTDE port) on purpose; here the two copies are held to each other."""
    from drivers.abb_rws import ABB_FACTORY_PASSWORD, ABB_FACTORY_USER, AbbRwsConfig
    from drivers.ur_rtde import UrRtdeConfig

    cfg = SimConfig()
    assert (cfg.robot_abb_rws.username, cfg.robot_abb_rws.password) == (
        ABB_FACTORY_USER,
        ABB_FACTORY_PASSWORD,
    )
    assert AbbRwsConfig.model_fields["username"].default == ABB_FACTORY_USER
    assert cfg.robot_ur_rtde.port == UrRtdeConfig.model_fields["port"].default == 30004
