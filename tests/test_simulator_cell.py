"""The emulated cell: truth from calib's TrueCell, motion, quantisation, status bits, the
slave-side codec, the control port, and ``cablecal simulate``'s READY line."""

from __future__ import annotations

import json
import math
import os
import re
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from helpers import sim_config

from calib.models import builtin_model
from calib.synthetic import make_true_cell
from drivers.wire_bytes import add_crc, rtu_read_request
from simulator.cell import EmulatedCell
from simulator.runner import READY_KEYS, ControlClient, SimulatorThread
from simulator.servers import ur_joint_registers
from simulator.wire import IndicatorBank, decode_mbap, decode_rtu_request

ROOT = Path(__file__).resolve().parents[1]


def test_cell_truth_is_calibs_true_cell() -> None:
    cell = EmulatedCell(sim_config())
    ref = make_true_cell(builtin_model("hsr-jr680"))  # defaults: Table XII D1, same P0 and c
    np.testing.assert_allclose(cell.truth.theta, ref.theta)
    now = time.monotonic()
    q, index, moving = cell.motion(now)
    assert index == 0 and not moving
    assert cell.true_length_mm(now) == pytest.approx(float(ref.lengths_mm(q[None, :])[0]))


def test_motion_interpolates_and_settles() -> None:
    cell = EmulatedCell(sim_config(robot={"move_time_s": 1.0, "dwell_s": 1.0}))
    t0 = cell._t0
    p = cell.poses_deg
    q_mid, i, moving = cell.motion(t0 + 1.5)
    assert moving and i == 0
    np.testing.assert_allclose(q_mid, (p[0] + p[1]) / 2)  # quintic profile: half way at s=0.5
    q_end, i, moving = cell.motion(t0 + 2.2)
    assert not moving and i == 1
    np.testing.assert_allclose(q_end, p[1])


def test_quantisation_and_over_range_status() -> None:
    cell = EmulatedCell(sim_config(indicator={"noise_mm": 0.0, "decimals": 1}))
    cell.hold(True)
    counts, status, _ = cell.indicator_state()
    assert counts == round(cell.true_length_mm() * 10) and status == 0
    cell.faults.update({"over_range": True})
    counts, status, _ = cell.indicator_state()
    assert status & 1 and counts == 20000
    with pytest.raises(ValueError, match="unknown fault"):
        cell.faults.update({"bogus": 1})


def test_poses_from_csv(tmp_path: Path) -> None:
    csv = tmp_path / "poses.csv"
    csv.write_text("q1,q2,q3,q4,q5,q6\n0,-30,200,0,20,0\n10,-40,210,5,25,5\n")
    cell = EmulatedCell(sim_config(robot={"poses": str(csv)}))
    np.testing.assert_allclose(cell.poses_deg[1], [10, -40, 210, 5, 25, 5])


def test_slave_codec_and_register_bank() -> None:
    cell = EmulatedCell(sim_config(indicator={"registers": {"word_order": "CDAB"}}))
    cell.hold(True)
    bank = IndicatorBank(cell)
    request = rtu_read_request(1, 3, 0, 8)
    assert decode_rtu_request(request[:5]) == (0, 0, None)  # incomplete: wait
    used, dev, pdu = decode_rtu_request(b"\x99" + request)  # garbage first: re-sync
    assert (used, pdu) == (1, None)
    used, dev, pdu = decode_rtu_request(request)
    assert (used, dev) == (8, 1) and pdu is not None
    reply = bank.handle(pdu)
    counts, _, _ = cell.indicator_state()
    lo, hi = int.from_bytes(reply[2:4], "big"), int.from_bytes(reply[4:6], "big")
    assert (hi << 16 | lo) == counts  # CDAB: low word first
    assert bank.handle(bytes.fromhex("04 00 00 00 02"))[0] == 0x84  # FC04 not configured
    assert bank.handle(bytes.fromhex("03 02 00 00 02")) == bytes.fromhex("83 02")
    frame = add_crc(bytes.fromhex("01 03 00 00 00 02"))
    assert decode_rtu_request(frame[:-1] + bytes([frame[-1] ^ 1]))[2] is None  # bad CRC
    assert decode_mbap(bytes.fromhex("00 07 00 00 00 06 01 03 00 00 00 02")) == (
        12,
        (7, 1),
        bytes.fromhex("03 00 00 00 02"),
    )


@pytest.mark.parametrize("q_rad", [0.0, 0.5, -0.5, 3.0, -3.0, 6.2831, -6.2831, 7.0])
def test_ur_registers_round_trip(q_rad: float) -> None:
    reg, rev = ur_joint_registers(q_rad)
    rev_signed = rev - 0x10000 if rev >= 0x8000 else rev
    assert 0 <= reg <= 6283
    assert reg / 1000 + rev_signed * 2 * math.pi == pytest.approx(q_rad, abs=0.0005 + 1e-9)


def test_control_port_commands() -> None:
    with SimulatorThread(sim_config()) as sim:
        assert set(sim.ready) == set(READY_KEYS)
        truth = sim.control("truth")
        assert truth["names"][-4:] == ["p0_x", "p0_y", "p0_z", "offset"]
        assert truth["anchor_p0_mm"] == [1400.0, 300.0, 200.0]
        assert truth["values"][0] == pytest.approx(0.0269)  # Table XII D1, deg
        poses = sim.control("poses")["poses_deg"][:2]
        lengths = sim.control("true_lengths", joints_deg=poses)["lengths_mm"]
        expected = sim.cell.truth.lengths_mm(np.array(poses))
        np.testing.assert_allclose(lengths, expected)
        state = sim.control("hold", on=True)
        assert state["held"]
        with pytest.raises(RuntimeError, match="unknown cmd"):
            sim.control("explode")
        with pytest.raises(RuntimeError, match="unknown fault"):
            sim.control("fault", nonsense=1)
        faults = sim.control("fault", indicator_drop_rate=0.25)["faults"]
        assert faults["indicator_drop_rate"] == 0.25
        assert sim.control("fault", clear=True)["faults"]["indicator_drop_rate"] == 0.0


def _free_port() -> int:
    """A free TCP port on 127.0.0.1, to request as a fixed one."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


@dataclass
class _Simulate:
    """A ``cablecal simulate`` process: its READY mapping; after it stopped, its exit code and
    stderr."""

    ready: dict[str, Any]
    returncode: int | None = None
    stderr: str = ""


@contextmanager
def _simulate(*module_args: str) -> Iterator[_Simulate]:
    """Run ``python -m MODULE_ARGS`` (the EMULATED cell) from the repository, wait for its
    ``READY {json}`` line and yield it parsed; on leaving, SIGTERM it and record its exit code
    and stderr. No READY line: the process is killed and the test fails with its stderr."""
    proc = subprocess.Popen(
        [sys.executable, "-m", *module_args],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert proc.stdout is not None
    line = proc.stdout.readline()
    if not line.startswith("READY "):
        proc.kill()
        _, err = proc.communicate(timeout=10)
        pytest.fail(f"no READY line, got {line!r}; stderr: {err[-2000:]}")
    run = _Simulate(json.loads(line[len("READY ") :]))
    try:
        yield run
    finally:
        proc.send_signal(signal.SIGTERM)
        _, run.stderr = proc.communicate(timeout=10)
        run.returncode = proc.returncode


def test_cablecal_simulate_prints_ready_and_stops_cleanly(tmp_path: Path) -> None:
    fixed = _free_port()
    cfg = tmp_path / "sim.toml"
    text = (ROOT / "examples" / "sim.toml").read_text()
    text, n = re.subn(r"(\[robot_socketcmd\][^\[]*?\nport = )0", rf"\g<1>{fixed}", text)
    assert n == 1
    cfg.write_text(text)
    with _simulate("simulator", "--config", str(cfg)) as sim:
        ready = sim.ready
        assert list(ready) == list(READY_KEYS)
        assert os.path.exists(ready["indicator_port"])
        assert ready["indicator_tcp"] is None
        assert ready["robot_socketcmd"] == f"127.0.0.1:{fixed}"  # fixed on request
        assert int(ready["robot_modbus"].rsplit(":", 1)[1]) > 0  # free by default, bound
        client = ControlClient(ready["control"])
        assert client("state")["n_poses"] == 60
        client.close()
    assert sim.returncode == 0
    assert not os.path.exists(ready["indicator_port"])  # the pty symlink is removed
    # The bound endpoints are also printed for humans (stderr).
    summary = next(line for line in sim.stderr.splitlines() if line.startswith("EMULATED cell"))
    for key in ("robot_socketcmd", "robot_modbus", "control", "indicator_port"):
        assert f"{key} {ready[key]}" in summary


def test_cablecal_simulate_port_options_override_the_config() -> None:
    fixed = _free_port()
    with _simulate("daemon.cli", "simulate", "--modbus-port", str(fixed)) as sim:
        assert sim.ready["robot_modbus"] == f"127.0.0.1:{fixed}"
        assert int(sim.ready["robot_socketcmd"].rsplit(":", 1)[1]) > 0  # unset: a free port
    bad = subprocess.run(
        [sys.executable, "-m", "daemon.cli", "simulate", "--control-port", "70000"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert bad.returncode == 2
    assert "--control-port" in bad.stderr
