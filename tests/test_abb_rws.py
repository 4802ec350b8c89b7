"""ABB RWS (issue 18): the emulated face read by ABB's public client (abb_robot_client's
``RWS``) and by our driver, RWS 1.0 (HTTP + digest) and 2.0 (HTTPS + basic), with faults."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from abb_robot_client.rws import RWS
from helpers import deviation_from_truth_deg, host_port, start_emulated_cell

from drivers import AbbRwsConfig, AbbRwsRobot, RobotLinkDown, RobotProtocolError, make_robot
from drivers.credentials import CredentialsError, write_secret
from drivers.errors import DeviceError
from simulator.faces.abb_rws import AbbRwsServer
from simulator.runner import SimulatorThread

pytestmark = pytest.mark.anyio

#: A reading of the brand's client must match the emulated truth to this [deg].
AGREE_DEG = 0.01
PASSWORD = "robotics"  # the EMULATED controller's factory-default login


@pytest.fixture(autouse=True)
def _password(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("CABLECAL_ROBOT_PASSWORD", PASSWORD)


@pytest.fixture
def moving_cell() -> Iterator[SimulatorThread]:
    """Emulated cell whose robot always moves: a stale value differs from the truth."""
    s = start_emulated_cell(robot={"move_time_s": 4.0, "dwell_s": 0.0}, indicator={"pty": False})
    try:
        yield s
    finally:
        s.stop()


def _face(sim: SimulatorThread) -> AbbRwsServer:
    assert sim.runner is not None
    face = sim.runner.faces["robot_abb_rws"]
    assert isinstance(face, AbbRwsServer)
    return face


def _robot(sim: SimulatorThread, **cfg: Any) -> AbbRwsRobot:
    host, port = host_port(sim.ready["robot_abb_rws"])
    return AbbRwsRobot(AbbRwsConfig(host=host, port=port, **cfg))


def test_abb_robot_client_reads_the_emulated_jointtarget(moving_cell: SimulatorThread) -> None:
    """abb_robot_client's RWS (requests, digest auth, ``?json=1``) reads the jointtarget of
    the moving robot: each value is the truth at an instant of its request, to 0.01 deg."""
    client = RWS(f"http://{moving_cell.ready['robot_abb_rws']}", "Default User", PASSWORD)
    rows: list[tuple[float, Any, float]] = []
    # At least 20 reads over at least 1 s: a fixed count alone takes ~0.2 s on a quiet
    # machine, too little for the robot to move the degree asserted below.
    start = time.monotonic()
    while len(rows) < 20 or time.monotonic() - start < 1.0:
        t0 = time.monotonic()
        target = client.get_jointtarget("ROB_1")
        rows.append((t0, target.robax, time.monotonic()))
        time.sleep(0.01)
    errors = [deviation_from_truth_deg(moving_cell, q, t0, t1) for t0, q, t1 in rows]
    assert max(errors) <= AGREE_DEG, errors
    assert np.ptp([q for _, q, _ in rows], axis=0).max() > 1.0  # the robot did move
    assert _face(moving_cell).statuses == {401: 1, 200: len(rows)}  # one login, then its session
    wrong = RWS(f"http://{moving_cell.ready['robot_abb_rws']}", "Default User", "wrong")
    with pytest.raises(Exception, match="Unauthorized"):
        wrong.get_jointtarget()


async def test_driver_under_drops_and_late_replies_returns_only_fresh_truth(
    moving_cell: SimulatorThread,
) -> None:
    """10 % of responses dropped, 20 % sent 0.3 s late (after the 0.2 s first-attempt
    timeout): every reading is the truth at an instant between the start of its read and its
    stamp; a late response taken for a retry's would be 0.3 s stale (degrees off)."""
    moving_cell.control("fault", robot_drop_rate=0.1, robot_late_rate=0.2, robot_late_delay_s=0.3)
    robot = _robot(moving_cell)
    checked = []
    failed = 0
    try:
        for _ in range(15):
            t_asked = time.monotonic()
            try:
                checked.append((await robot.read_joints(), t_asked))
            except DeviceError:
                failed += 1
    finally:
        await robot.close()
    assert robot.attempts.silent_total >= 3  # the faults were exercised
    assert len(checked) >= 12, failed
    for reading, t_asked in checked:
        dev = deviation_from_truth_deg(
            moving_cell, reading.joints_deg, t_asked, reading.t_monotonic_s
        )
        assert dev <= 0.002, f"{reading} is {dev:.4f} deg from the truth"


async def test_driver_recovers_after_link_down(moving_cell: SimulatorThread) -> None:
    robot = _robot(moving_cell, timeout_s=0.3, fast_reply_timeout_s=0.1)
    try:
        await robot.read_joints()
        moving_cell.control("link_down", target="robot_abb_rws", duration_s=0.4)
        failures: list[str] = []
        t_end = time.monotonic() + 4.0
        while time.monotonic() < t_end:
            t_asked = time.monotonic()
            try:
                reading = await robot.read_joints()
            except DeviceError as exc:
                failures.append(type(exc).__name__)
                await asyncio.sleep(0.05)
                continue
            if failures:
                break
        assert failures and set(failures) <= {"RobotLinkDown", "RobotTimeout"}, failures
        assert robot.connects >= 2  # an HTTP client re-made after the lost link
        dev = deviation_from_truth_deg(
            moving_cell, reading.joints_deg, t_asked, reading.t_monotonic_s
        )
        assert dev <= 0.002
    finally:
        await robot.close()
    face = _face(moving_cell)
    assert face.statuses[401] == 1  # the session survived the link-down: one login only
    assert not face._sessions  # logged out on close


async def test_wrong_password_is_a_clear_error_that_never_shows_it(
    moving_cell: SimulatorThread, monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    secret = "not-the-Password-42"
    monkeypatch.setenv("CABLECAL_ROBOT_PASSWORD", secret)
    robot = _robot(moving_cell)
    with pytest.raises(RobotProtocolError, match=r"HTTP 401.*refused user 'Default User'") as info:
        await robot.read_joints()
    await robot.close()
    shown = [repr(robot.config), str(robot.config.model_dump()), info.value.report()]
    assert not any(secret in text for text in shown)
    # A password file readable by others is refused, naming the file and the fix.
    path = write_secret(tmp_path / "rws-password", PASSWORD)
    path.chmod(0o640)
    host, port = host_port(moving_cell.ready["robot_abb_rws"])
    with pytest.raises(CredentialsError, match=r"mode 0640.*chmod 600"):
        make_robot({"kind": "abb-rws", "host": host, "port": port, "password_file": str(path)})


async def test_rws2_https_basic_auth_with_the_controllers_certificate() -> None:
    """RWS 2.0 (OmniCore): HTTPS with the face's self-signed certificate pinned by
    ``ca_file``, basic auth, HAL JSON; without the certificate the TLS check refuses."""
    sim = start_emulated_cell(hold=True, indicator={"pty": False}, robot_abb_rws={"rws": "2.0"})
    try:
        cert = _face(sim).cert_path
        assert cert is not None
        robot = _robot(sim, rws="2.0", ca_file=cert)
        truth = np.asarray(sim.control("state")["joints_deg"])
        try:
            reading = await robot.read_joints()
        finally:
            await robot.close()
        assert np.abs(np.asarray(reading.joints_deg) - truth).max() <= 1e-6
        unpinned = _robot(sim, rws="2.0")
        with pytest.raises(RobotLinkDown, match="CERTIFICATE_VERIFY_FAILED"):
            await unpinned.read_joints()
        await unpinned.close()
    finally:
        sim.stop()
