"""Lossy robot links (issue 11, defect 7): a dropped reply is retried at once on the same
connection, a late reply is never taken for the retry's, and the link is re-opened only
after several silent attempts in a row.

Against the emulated cell (``robot_drop_rate``, and the emulated late-reply fault
``robot_late_rate`` / ``robot_late_delay_s``) and against scripted peers that state the exact
bytes (:mod:`drivers.testing`).

The emulated-cell fixtures here are local on purpose: tests/conftest.py with the shared
``sim`` fixture (``emulated_cell`` marker) was written in parallel; switch to it once merged.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
from expected_protocol import expected_protocol_tcp

from drivers import (
    DeviceError,
    HuashuConfig,
    HuashuSocketCmdRobot,
    ModbusRobotConfig,
    ModbusTcpRobot,
    RobotTimeout,
)
from drivers.backoff import SilentAttempts
from simulator.config import SimConfig
from simulator.runner import SimulatorThread

pytestmark = pytest.mark.anyio
Robot = HuashuSocketCmdRobot | ModbusTcpRobot
KINDS = ("huashu", "modbus")
#: Largest |reading - truth| of a held robot [deg]: SocketCmd sends 6 decimals, UR 1 mrad.
RESOLUTION_DEG = {"huashu": 1e-5, "modbus": 0.03}


def _cell(seed: int, **sections: Any) -> SimulatorThread:
    """Emulated cell on free TCP ports (``sections``: config sections), started."""
    ports = {"port": 0}
    config = {"seed": seed, "robot_socketcmd": ports, "robot_modbus": ports, "control": ports}
    return SimulatorThread(SimConfig.model_validate({**config, **sections})).start()


def _robot(sim: SimulatorThread, kind: str, **cfg: Any) -> Robot:
    endpoint = sim.ready["robot_socketcmd" if kind == "huashu" else "robot_modbus"]
    assert endpoint is not None
    host, port = endpoint.rsplit(":", 1)
    if kind == "huashu":
        return HuashuSocketCmdRobot(HuashuConfig(host=host, port=int(port), **cfg))
    return ModbusTcpRobot(ModbusRobotConfig(host=host, port=int(port), **cfg))


@pytest.fixture
def held_cell() -> Iterator[SimulatorThread]:
    """Emulated cell, robot held still; the seed fixes the sequence of emulated drops."""
    s = _cell(seed=11)
    s.control("hold", on=True)
    try:
        yield s
    finally:
        s.stop()


@pytest.fixture
def moving_cell() -> Iterator[SimulatorThread]:
    """Emulated cell, robot always moving (no dwell): a stale reading differs from the truth."""
    s = _cell(seed=5, robot={"move_time_s": 1.0, "dwell_s": 0.0})
    try:
        yield s
    finally:
        s.stop()


# --------------------------------------------------------------------------- retry policy
def test_silent_attempts_policy() -> None:
    policy = SilentAttempts(retries=2, reconnect_after=3, fast_timeout_s=0.2, last_timeout_s=1.0)
    assert policy.timeouts_s() == [0.2, 0.2, 1.0]
    assert [policy.silent(0), policy.silent(1)] == ["retry", "retry"]
    policy.replied(attempt=2)  # a reply resets the run of silent attempts
    assert [policy.silent(0), policy.silent(1)] == ["retry", "retry"]
    assert policy.silent(2) == "reopen"  # the third in a row: re-open the connection
    assert (policy.silent_total, policy.recovered_total) == (5, 1)
    assert policy.failure_text(2) == "no reply to 3 attempt(s) (waited 0.2, 0.2, 1 s)"
    policy.reset()
    assert SilentAttempts(0, 3, 0.2, 1.0).silent(0) == "fail"  # no retries left
    # The last attempt never waits less than the others.
    assert SilentAttempts(0, 1, 0.5, 0.1).timeouts_s() == [0.5]
    for bad in ({"retries": -1}, {"reconnect_after": 0}, {"fast_timeout_s": 0.0}):
        args: dict[str, Any] = {
            "retries": 1,
            "reconnect_after": 1,
            "fast_timeout_s": 0.1,
            "last_timeout_s": 1.0,
            **bad,
        }
        with pytest.raises(ValueError, match=next(iter(bad))):
            SilentAttempts(**args)


# --------------------------------------------------------------------------- exact bytes
HS_REQ = "i:{},c:mot.getJntData(0)@hs@"


def _mbap_request(tid: int) -> bytes:
    """UR preset block read 270..325 (56 registers), unit 1."""
    return tid.to_bytes(2, "big") + bytes.fromhex("0000 0006 01 03 010e 0038")


def _mbap_reply(tid: int, first_angle: int) -> bytes:
    regs = [first_angle] + [0] * 55
    pdu = bytes.fromhex("03 70") + b"".join(r.to_bytes(2, "big") for r in regs)
    return (
        tid.to_bytes(2, "big")
        + bytes.fromhex("0000")
        + (len(pdu) + 1).to_bytes(2, "big")
        + (b"\x01" + pdu)
    )


async def test_huashu_dropped_reply_is_retried_at_once_and_late_reply_ignored() -> None:
    """Regression: a dropped reply cost the whole 1 s timeout and failed the read. Now the
    retry (new sequence number) follows after ``fast_reply_timeout_s``, on the same
    connection, and the late reply to the first request, arriving just before the retry's,
    is discarded."""
    exchanges = [
        (HS_REQ.format(1).encode(), b""),  # dropped
        (
            HS_REQ.format(2).encode(),
            b"i:1,e:0,d:{9,9,9,9,9,9,}@hs@"  # late reply to the first request
            b"i:2,e:0,d:{1.5,2,3,4,5,6,}@hs@",
        ),
    ]
    async with expected_protocol_tcp(exchanges) as port:
        robot = HuashuSocketCmdRobot(HuashuConfig(port=port))
        t0 = time.monotonic()
        reading = await robot.read_joints()
        took_s = time.monotonic() - t0
        await robot.close()
    assert reading.joints_deg == (1.5, 2.0, 3.0, 4.0, 5.0, 6.0)
    assert robot.connects == 1
    assert (robot.attempts.silent_total, robot.attempts.recovered_total) == (1, 1)
    assert 0.19 <= took_s < 0.6, took_s  # fast_reply_timeout_s = 0.2, not timeout_s = 1


async def test_modbus_dropped_reply_is_retried_with_a_new_transaction_id() -> None:
    """Regression: same for Modbus TCP. The retry carries transaction id 2 (pymodbus' own
    retries would re-send id 1 and accept the late reply to it); the late reply with id 1,
    arriving first, is skipped."""
    exchanges = [
        (_mbap_request(1), b""),  # dropped
        (_mbap_request(2), _mbap_reply(1, 3000) + _mbap_reply(2, 1000)),
    ]
    async with expected_protocol_tcp(exchanges) as port:
        robot = ModbusTcpRobot(ModbusRobotConfig(port=port))
        t0 = time.monotonic()
        reading = await robot.read_joints()
        took_s = time.monotonic() - t0
        await robot.close()
    assert reading.joints_deg[0] == pytest.approx(np.degrees(1.0))  # 1000 mrad, not 3000
    assert robot.connects == 1
    assert (robot.attempts.silent_total, robot.attempts.recovered_total) == (1, 1)
    assert 0.19 <= took_s < 0.6, took_s


async def test_huashu_reply_newer_than_any_request_resets_the_connection() -> None:
    """A frame that answers no request sent cannot be attributed: never returned; the
    connection is closed so the stream re-synchronises."""
    exchanges = [(HS_REQ.format(1).encode(), b"i:7,e:0,d:{9,9,9,9,9,9,}@hs@")]
    async with expected_protocol_tcp(exchanges) as port:
        robot = HuashuSocketCmdRobot(HuashuConfig(port=port))
        with pytest.raises(DeviceError, match="newer than the request"):
            await robot.read_joints()
        assert not robot.connected
        await robot.close()


# --------------------------------------------------------------------------- emulated cell
@pytest.mark.parametrize("kind", KINDS)
async def test_reads_survive_10_percent_dropped_replies(
    held_cell: SimulatorThread, kind: str
) -> None:
    """At 10 % emulated drops, >= 95 % of N reads succeed (before the fix: about 90 %, one
    1 s timeout each), single drops cost no reconnect, and every value is the truth."""
    n = 120
    truth = np.asarray(held_cell.control("state")["joints_deg"])
    held_cell.control("fault", robot_drop_rate=0.1)
    robot = _robot(held_cell, kind)
    good: list[tuple[float, ...]] = []
    t0 = time.monotonic()
    try:
        for _ in range(n):
            with contextlib.suppress(RobotTimeout):
                good.append((await robot.read_joints()).joints_deg)
    finally:
        await robot.close()
    took_s = time.monotonic() - t0
    assert len(good) >= 0.95 * n, f"{len(good)}/{n} reads"
    assert robot.attempts.silent_total >= 5  # the fault was exercised
    # Seed 11 has no 3 drops in a row in this run: no reconnect at all.
    assert robot.connects == 1, robot.frames.snapshot()
    assert np.abs(np.asarray(good) - truth).max() <= RESOLUTION_DEG[kind]
    # Each drop costs one fast_reply_timeout_s (0.2 s), not timeout_s (1 s).
    assert took_s < 0.35 * robot.attempts.silent_total + 0.05 * n, took_s


def _deviation_from_truth_deg(
    sim: SimulatorThread, joints_deg: tuple[float, ...], t_from_s: float, t_to_s: float
) -> float:
    """``min_t max_j |q_j(t) - reading_j|`` [deg] over t in [t_from_s, t_to_s]: how far
    the reading is from the cell's truth at any instant of that span (0.5 ms grid, then
    0.01 ms around the best instant; joints move at up to a few hundred deg/s)."""
    reading = np.asarray(joints_deg)

    def best(times_s: np.ndarray) -> tuple[float, float]:
        devs = [float(np.abs(sim.cell.reported_joints(t) - reading).max()) for t in times_s]
        k = int(np.argmin(devs))
        return float(times_s[k]), devs[k]

    t_best, _ = best(np.arange(t_from_s - 0.001, t_to_s + 0.0005, 0.0005))
    return best(np.arange(t_best - 0.0006, t_best + 0.0006, 0.00001))[1]


def _last_tx_s(robot: Robot) -> float:
    """Monotonic time [s] of the last request sent (the driver's frame log)."""
    return max(float(line.split()[0]) for line in robot.frames.snapshot() if " tx " in line)


@pytest.mark.parametrize("kind", KINDS)
async def test_late_replies_are_never_taken_for_the_retry(
    moving_cell: SimulatorThread, kind: str
) -> None:
    """20 % of replies arrive 0.3 s late (after the 0.2 s fast_reply_timeout_s, just before
    the retry's reply), the robot moves all the time. Every reading must be the cell's truth
    at an instant between the sending of the last request and the reading's stamp; a late
    reply to the first attempt, taken for the retry's, would be the truth 0.2 s before that
    span (the robot moves several degrees in 0.2 s)."""
    moving_cell.control("fault", robot_late_rate=0.2, robot_late_delay_s=0.3)
    robot = _robot(moving_cell, kind)
    checked = []
    try:
        for _ in range(40):
            reading = await robot.read_joints()
            checked.append((reading, _last_tx_s(robot)))
    finally:
        await robot.close()
    assert robot.attempts.recovered_total >= 3  # late replies were in flight
    tol_deg = RESOLUTION_DEG[kind] + 0.01  # + motion within one 0.01 ms grid step
    for reading, t_tx_s in checked:
        dev_deg = _deviation_from_truth_deg(
            moving_cell, reading.joints_deg, t_tx_s, reading.t_monotonic_s
        )
        assert dev_deg <= tol_deg, f"{reading} is {dev_deg:.3f} deg from the truth"


@pytest.mark.parametrize("kind", KINDS)
async def test_silent_peer_is_reopened_after_consecutive_timeouts(
    held_cell: SimulatorThread, kind: str
) -> None:
    """A peer that stops answering is re-opened after ``reconnect_after_timeouts`` silent
    attempts in a row, and reads come back once it answers again."""
    robot = _robot(held_cell, kind, timeout_s=0.1, fast_reply_timeout_s=0.05)
    try:
        await robot.read_joints()
        held_cell.control("fault", robot_drop_rate=1.0)
        with pytest.raises(RobotTimeout):
            await robot.read_joints()  # 3 silent attempts: connection closed
        assert not robot.connected
        held_cell.control("fault", robot_drop_rate=0.0)
        await robot.read_joints()
    finally:
        await robot.close()
    assert robot.connects == 2
