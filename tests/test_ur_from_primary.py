"""``cablecal robots from-ur HOST`` (issue 34 item 3, UR): the arm's own table, read from the
EMULATED cell's primary interface (port 30001 beside its RTDE face), is the model file it
prints: the cell's true table, with the library arm's joint ranges; refusals exit 2."""

from __future__ import annotations

import tomllib
from collections.abc import Iterator

import numpy as np
import pytest
from helpers import host_port, start_emulated_cell
from typer.testing import CliRunner

from calib.models import builtin_model, model_from_mapping
from daemon.cli import app
from simulator.faces.ur_primary import UrPrimaryServer
from simulator.faces.ur_rtde import UrRtdeServer
from simulator.runner import SimulatorThread

runner = CliRunner()


@pytest.fixture(scope="module")
def ur_cell() -> Iterator[SimulatorThread]:
    """An emulated UR10e whose true table has the errors of the paper's Table XII."""
    sim = start_emulated_cell(
        hold=True, robot={"model": "ur10e", "dh_errors": "table-xii-d1"}, indicator={"pty": False}
    )
    try:
        yield sim
    finally:
        sim.stop()


def _primary(sim: SimulatorThread) -> UrPrimaryServer:
    assert sim.runner is not None
    face = sim.runner.faces["robot_ur_rtde"]
    assert isinstance(face, UrRtdeServer) and face.primary is not None
    return face.primary


def test_from_ur_prints_the_arms_own_table(ur_cell: SimulatorThread) -> None:
    primary = _primary(ur_cell)
    host, port = host_port(primary.endpoint)
    assert port == 30001  # UR's own port, on the RTDE face's address
    r = runner.invoke(app, ["robots", "from-ur", host])
    assert r.exit_code == 0, r.output
    model = model_from_mapping(tomllib.loads(r.stdout))
    truth = primary.true_table()
    assert truth is not None
    # The file's table [deg, mm] is the cell's true one [rad, mm] to the doubles' precision.
    got = np.array(model.dh_table, dtype=float)
    want = truth.copy()
    want[:, [0, 3]] = np.degrees(want[:, [0, 3]])
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)
    # The errors are there: the file is not the published table.
    base = builtin_model("ur10e")
    assert np.max(np.abs(got - np.array(base.dh_table, dtype=float))) > 0.1
    assert model.name == "ur10e-factory" and model.controller == base.controller
    np.testing.assert_array_equal(model.limits_deg(), base.limits_deg())
    assert f"The arm at {host}:30001 as its controller computes" in r.stdout
    named = runner.invoke(app, ["robots", "from-ur", host, "--base", "ur10e", "--name", "cell7"])
    assert named.exit_code == 0 and model_from_mapping(tomllib.loads(named.stdout)).name == "cell7"


def test_from_ur_refusals_exit_2_with_a_reason(ur_cell: SimulatorThread) -> None:
    host, _ = host_port(_primary(ur_cell).endpoint)
    wrong = runner.invoke(app, ["robots", "from-ur", host, "--base", "abb-irb120"])
    assert wrong.exit_code == 2 and "a UR factory calibration applies to a UR model" in " ".join(
        wrong.output.split()
    )
    # The RTDE port is no primary interface: its first bytes are no message header.
    rtde_host, rtde_port = host_port(ur_cell.runner.faces["robot_ur_rtde"].endpoint)  # type: ignore[union-attr]
    other = runner.invoke(
        app, ["robots", "from-ur", rtde_host, "--port", str(rtde_port), "--timeout-s", "1"]
    )
    assert other.exit_code == 2 and "error:" in other.output and "Traceback" not in other.output
    closed = runner.invoke(
        app, ["robots", "from-ur", "127.0.0.1", "--port", "9", "--timeout-s", "1"]
    )
    assert closed.exit_code == 2 and "127.0.0.1:9: cannot connect" in closed.output


def test_the_base_arm_is_found_by_d1_and_a3_whatever_a2_and_d2_do() -> None:
    """A real factory calibration moves a2 by hundreds of mm and d2..d4 by hundreds of
    metres, d1 and a3 by a few mm (ur_calibration's test calibrations): the arm is still
    found; a size no library arm has asks for the base by name."""
    from calib.models import ModelError
    from calib.robots.ur_factory import SAME_ARM_MM, library_ur_arm

    a = [0.0, -0.6127 + 0.632, -0.57155 + 0.0023, 0.0, 0.0, 0.0]
    d = [0.1807 - 0.0002, 439.1, -446.0, 0.17415 + 6.9, 0.11985, 0.11655]
    assert library_ur_arm(a, d) == "ur10e"
    assert library_ur_arm([0, -0.425, -0.3922, 0, 0, 0], [0.1625, 0, 0, 0, 0, 0]) == "ur5e"
    assert library_ur_arm([0, -0.4784, -0.36, 0, 0, 0], [0.1807, 0, 0, 0, 0, 0]) == "ur16e"
    off = [0.1807 + 2 * SAME_ARM_MM / 1000.0, 0, 0, 0, 0, 0]
    with pytest.raises(ModelError) as err:
        library_ur_arm(a, off)
    assert "give its base arm by name" in str(err.value)
