"""The emulated robot follows a plan: poses from a plan CSV (``q1..q6`` by header, as
``cablecal plan`` writes and ``cablecal identify`` reads) or from the ``load_poses`` control
command, visited in order with the usual move/dwell; bad CSV names the row and column."""

from __future__ import annotations

import asyncio
import csv
import time
from pathlib import Path

import numpy as np
import pytest

from calib.planning import CSV_COLUMNS
from drivers import HuashuConfig, HuashuSocketCmdRobot
from simulator.cell import EmulatedCell
from simulator.config import SimConfig
from simulator.poses import PoseCsvError, parse_poses_csv
from simulator.runner import SimulatorThread

pytestmark = pytest.mark.anyio

#: Poses [deg] within the JR680's limits (q3 reads 60..300 deg), all different.
PLAN_DEG = np.array(
    [
        [0.0, -30.0, 200.0, 0.0, 20.0, 0.0],
        [15.0, -45.0, 215.0, 10.0, 35.0, -20.0],
        [-20.0, -20.0, 185.0, -15.0, 10.0, 30.0],
        [30.0, -60.0, 230.0, 25.0, 45.0, 10.0],
    ]
)


def write_plan_csv(path: Path, q_deg: np.ndarray) -> Path:
    """A CSV in the layout of ``cablecal plan`` (calib.planning.CSV_COLUMNS): ``pose`` first,
    then q1..q6, then anchor/extension columns the emulated cell must ignore."""
    with path.open("w", newline="", encoding="utf-8") as fh:
        writer = csv.writer(fh)
        writer.writerow(CSV_COLUMNS)
        for i, q in enumerate(q_deg):
            writer.writerow([i + 1, *q, "A", 900.0 + i, 1400.0, 300.0, 200.0])
    return path


def test_plan_csv_is_read_by_header_ignoring_extra_columns(tmp_path: Path) -> None:
    path = write_plan_csv(tmp_path / "plan.csv", PLAN_DEG)
    cell = EmulatedCell(SimConfig(robot={"poses": str(path)}))
    np.testing.assert_array_equal(cell.poses_deg, PLAN_DEG)  # not shifted by the pose column
    # Column order does not matter; case does not matter; a header-less file is 6 columns.
    text = "Q6,q5,x,q4,q3,q2,q1\n" + "".join(
        f"{q[5]},{q[4]},999,{q[3]},{q[2]},{q[1]},{q[0]}\n" for q in PLAN_DEG
    )
    np.testing.assert_array_equal(parse_poses_csv(text), PLAN_DEG)
    bare = "\n".join(",".join(str(v) for v in q) for q in PLAN_DEG)
    np.testing.assert_array_equal(parse_poses_csv(bare), PLAN_DEG)


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("q1,q2,q4,q5,q6\n1,2,3,4,5\n", r"row 1: .*missing column\(s\) \['q3'\]"),
        ("q1,q2,q3,q4,q5,q6\n0,0,200,0,0,0\n0,0,200,abc,0,0\n", r"row 3, column 'q4'.*'abc'"),
        ("q1,q2,q3,q4,q5,q6\n0,0,200,0,0\n", r"row 2, column 'q6': .*missing value"),
        ("q1,q2,q3,q4,q5,q6\n0,0,200,0,0,nan\n", r"row 2, column 'q6'.*not finite"),
        ("q1,q2,q3,q4,q5,q6\n0,0,20,0,0,0\n", r"row 2, column 'q3'.*outside the joint limits"),
        ("q1,q2,q3,q4,q5,q6\n", "no poses after the header"),
        ("\n\n", "empty file"),
    ],
)
def test_bad_plan_csv_names_row_and_column(tmp_path: Path, text: str, match: str) -> None:
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(PoseCsvError, match=match):
        EmulatedCell(SimConfig(robot={"poses": str(path)}))


def test_missing_plan_file_is_a_clear_error(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"robot.poses: cannot read .*nope.csv"):
        EmulatedCell(SimConfig(robot={"poses": "nope.csv"}, base_dir=str(tmp_path)))


def test_schedule_visits_exactly_the_plan_in_order(tmp_path: Path) -> None:
    path = write_plan_csv(tmp_path / "plan.csv", PLAN_DEG)
    cell = EmulatedCell(
        SimConfig(robot={"poses": str(path), "dwell_s": 1.0, "move_time_s": 0.5, "loop": False})
    )
    t0 = cell._t0
    for i, q in enumerate(PLAN_DEG):
        joints, index, moving = cell.motion(t0 + 1.5 * i + 0.5)  # mid-dwell at pose i
        assert (index, moving) == (i, False)
        np.testing.assert_array_equal(joints, q)
    joints, index, moving = cell.motion(t0 + 100.0)  # loop = false: stays at the last pose
    assert (index, moving) == (3, False)
    np.testing.assert_array_equal(joints, PLAN_DEG[-1])


def test_load_poses_moves_from_where_the_robot_is() -> None:
    cell = EmulatedCell(SimConfig(robot={"dwell_s": 1.0, "move_time_s": 0.5}))
    now = time.monotonic()
    before, _, _ = cell.motion(now)
    cell.load_poses(PLAN_DEG, loop=False, now=now)
    assert cell.state_report(now)["n_poses"] == 4 and not cell.loop
    q, index, moving = cell.motion(now)
    assert moving and index == 0
    np.testing.assert_allclose(q, before)  # no jump
    q, _, moving = cell.motion(now + 0.25)
    assert moving
    np.testing.assert_allclose(q, (before + PLAN_DEG[0]) / 2)  # quintic: half way at s=0.5
    for i in range(4):
        q, index, moving = cell.motion(now + 0.5 + 1.5 * i + 0.5)
        assert (index, moving) == (i, False)
        np.testing.assert_array_equal(q, PLAN_DEG[i])
    with pytest.raises(ValueError, match=r"row 2, q3: 20.0 deg .*outside the joint limits"):
        cell.load_poses(np.vstack([PLAN_DEG[0], [0, 0, 20, 0, 0, 0]]))
    with pytest.raises(ValueError, match=r"expected shape \(n, 6\)"):
        cell.load_poses(np.zeros((2, 5)))


def _plateaus(readings: list[tuple[float, ...]], min_repeat: int = 3) -> list[tuple[float, ...]]:
    """Joint vectors reported at least ``min_repeat`` times in a row (the dwells), in order."""
    out: list[tuple[float, ...]] = []
    run = 0
    for k, q in enumerate(readings):
        run = run + 1 if k and np.allclose(q, readings[k - 1], atol=1e-9) else 1
        if run == min_repeat and (not out or not np.allclose(q, out[-1], atol=1e-9)):
            out.append(q)
    return out


async def _poll_joints(endpoint: str | None, duration_s: float) -> list[tuple[float, ...]]:
    assert endpoint is not None
    host, port = endpoint.rsplit(":", 1)
    robot = HuashuSocketCmdRobot(HuashuConfig(host=host, port=int(port)))
    readings = []
    try:
        end = time.monotonic() + duration_s
        while time.monotonic() < end:
            readings.append(tuple((await robot.read_joints()).joints_deg))
            await asyncio.sleep(0.02)
    finally:
        await robot.close()
    return readings


async def test_driver_sees_the_plan_csv_poses_in_order(tmp_path: Path) -> None:
    path = write_plan_csv(tmp_path / "plan.csv", PLAN_DEG)
    robot = {"poses": str(path), "dwell_s": 0.35, "move_time_s": 0.15, "loop": False}
    with SimulatorThread(SimConfig(robot=robot, indicator={"pty": False})) as sim:
        readings = await _poll_joints(sim.ready["robot_socketcmd"], 4 * 0.5 + 0.4)
    seen = _plateaus(readings)
    np.testing.assert_allclose(np.array(seen), PLAN_DEG, atol=1e-6)  # 6 decimals on the wire


async def test_load_poses_command_and_csv_over_the_control_port(tmp_path: Path) -> None:
    path = write_plan_csv(tmp_path / "plan.csv", PLAN_DEG[::-1])
    robot = {"dwell_s": 0.35, "move_time_s": 0.15}
    config = SimConfig(robot=robot, indicator={"pty": False}, base_dir=str(tmp_path))
    with SimulatorThread(config) as sim:
        reply = sim.control("load_poses", poses_deg=PLAN_DEG.tolist(), loop=False)
        assert reply["poses_deg"] == PLAN_DEG.tolist() and reply["loop"] is False
        readings = await _poll_joints(sim.ready["robot_socketcmd"], 0.15 + 4 * 0.5 + 0.4)
        np.testing.assert_allclose(np.array(_plateaus(readings)), PLAN_DEG, atol=1e-6)
        reply = sim.control("load_poses", csv=str(path))
        assert reply["poses_deg"] == PLAN_DEG[::-1].tolist()
        assert sim.control("poses")["poses_deg"] == PLAN_DEG[::-1].tolist()
        bad = tmp_path / "bad.csv"
        bad.write_text("pose,q1,q2,q3,q4,q5,q6\n1,0,0,200,0,0,0\n2,0,x,200,0,0,0\n")
        with pytest.raises(RuntimeError, match=r"row 3, column 'q2'"):
            sim.control("load_poses", csv=str(bad))
        with pytest.raises(RuntimeError, match="exactly one of"):
            sim.control("load_poses")
        assert sim.control("state")["n_poses"] == 4  # a failed load changes nothing


@pytest.mark.parametrize("fmt", ["rapid", "urscript", "krl", "fanuc-ls"])
def test_the_emulated_robot_runs_a_robot_program(tmp_path: Path, fmt: str) -> None:
    from calib.programs.common import JointProgram, round_joints
    from calib.programs.registry import write_program

    program = JointProgram("CAL", round_joints(PLAN_DEG.tolist()), speed_pct=20, dwell_s=1)
    path = tmp_path / f"CAL.{fmt}"
    path.write_text(write_program(fmt, program))
    cell = EmulatedCell(SimConfig(robot={"poses": str(path), "loop": False}))
    np.testing.assert_allclose(cell.poses_deg, PLAN_DEG, atol=1e-9)  # its joint moves, in order
    bad = JointProgram("CAL", ((0.0, 0.0, 20.0, 0.0, 0.0, 0.0),), speed_pct=20, dwell_s=1)
    path.write_text(write_program(fmt, bad))
    with pytest.raises(PoseCsvError, match=rf"\({fmt}\): target 1, q3: 20.0 deg is outside"):
        cell.read_poses_csv(str(path))
    path.write_text(write_program(fmt, program).replace("0.000", "0.0.0", 1))
    with pytest.raises(PoseCsvError, match=rf"\({fmt}\): line \d+"):
        cell.read_poses_csv(str(path))


def test_cablecal_emulated_robot_run_loads_a_program(tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from calib.programs.common import JointProgram, round_joints
    from calib.programs.registry import write_program
    from daemon.cli import app

    path = tmp_path / "CAL_PLAN.LS"
    program = JointProgram("CAL_PLAN", round_joints(PLAN_DEG.tolist()), speed_pct=20, dwell_s=1)
    path.write_text(write_program("fanuc-ls", program))
    with SimulatorThread(SimConfig(indicator={"pty": False})) as sim:
        control = str(sim.ready["control"])
        res = CliRunner().invoke(app, ["emulated-robot-run", str(path), "--control", control])
        assert res.exit_code == 0, res.output
        assert "the EMULATED robot runs CAL_PLAN.LS: 4 targets" in res.output
        np.testing.assert_allclose(sim.control("poses")["poses_deg"], PLAN_DEG, atol=1e-9)
        path.write_text("/PROG X\n/MN\n 1:J P[1] 50% CNT100 ;\n/POS\n/END\n")
        res = CliRunner().invoke(app, ["emulated-robot-run", str(path), "--control", control])
        assert res.exit_code == 2 and "CNT100 blends" in res.output
        assert sim.control("state")["n_poses"] == 4  # a bad program changes nothing


def test_the_control_port_reads_only_inside_its_directory(tmp_path: Path) -> None:
    """Issue 28, item 9: ``load_poses`` reads a path only when it leads, after ``..`` and
    symlinks, to a regular file inside the config's directory; a file that is not a poses
    file is refused without a byte of it in the reply."""
    cell_dir = tmp_path / "cell"
    cell_dir.mkdir()
    secret = tmp_path / "secret.txt"
    secret.write_text("root:SECRET-HASH:19000:0:99999:7:::\nSECRET=second-line\n")
    inside_secret = cell_dir / "notes.csv"
    inside_secret.write_text("SECRET-HEADER,x\nSECRET-CELL,1\n")
    (cell_dir / "link.csv").symlink_to(secret)
    (cell_dir / "sub").mkdir()
    write_plan_csv(cell_dir / "sub" / "plan.csv", PLAN_DEG)
    config = SimConfig(indicator={"pty": False}, base_dir=str(cell_dir))
    with SimulatorThread(config) as sim:
        refused = {
            "/etc/passwd": "outside the cell's config directory",
            "/proc/self/environ": "outside the cell's config directory",
            str(secret): "outside the cell's config directory",
            "../secret.txt": "outside the cell's config directory",
            "sub/../../secret.txt": "outside the cell's config directory",
            "link.csv": "outside the cell's config directory",  # a symlink out
            "sub": "no such file",
            "missing.csv": "no such file",
            "notes.csv": "notes.csv: not a valid poses file",
        }
        for key in ("csv", "program"):
            for path, reason in refused.items():
                with pytest.raises(RuntimeError) as info:
                    sim.control("load_poses", **{key: path})
                message = str(info.value)
                assert reason in message, (path, message)
                assert "SECRET" not in message and "root:" not in message, message
                assert "PATH=" not in message and "HOME=" not in message, message
        # Inside the directory, relative, through "..", or absolute: read.
        for path in ("sub/plan.csv", "sub/../sub/plan.csv", str(cell_dir / "sub/plan.csv")):
            reply = sim.control("load_poses", csv=path)
            np.testing.assert_allclose(reply["poses_deg"], PLAN_DEG)
        assert sim.control("state")["n_poses"] == len(PLAN_DEG)  # refusals changed nothing
