"""FANUC Remote Motion Interface: packets, the EMULATED RMI read by the public client
fanuc-rmi 0.3.1 (written by no one here), and our driver against the emulated RMI with faults
(drops, late replies, link down, frozen joints): no corrupt value is ever returned, every
failure is a typed error.

fanuc-rmi reads the session port from a ``Port`` key; the manual (B-84184EN/03, 2.2.1) and
FANUC's own C++ client name it ``PortNumber``, which is what the controller and our face send.
The client then falls back to its ``main_port`` argument (default 16002, the real
controller's session port), so the cross-check passes the face's session port there, as a
user of that client must on a real controller whose session port is not 16002.
"""

from __future__ import annotations

import asyncio
import json
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from expected_protocol import expected_protocol_tcp
from fanuc_rmi import RobotClient
from helpers import host_port, start_emulated_cell
from robot_faces import (
    drops_and_late_replies,
    frozen_joints_raise_stale,
    late_replies_never_taken,
    link_down_then_back,
)

from drivers.errors import RobotLinkDown, RobotProtocolError
from drivers.fanuc_rmi import (
    RMIT_ALREADY_CONNECTED,
    FanucRmiConfig,
    FanucRmiRobot,
    decode_packet,
    encode_packet,
    joint_angles,
)
from simulator.faces.fanuc_rmi import FanucRmiServer
from simulator.runner import SimulatorThread

pytestmark = pytest.mark.anyio
#: |reading - truth| of a held robot [deg]: the face sends 6 decimals.
RESOLUTION_DEG = 1e-5
Fanuc = tuple[SimulatorThread, FanucRmiServer]
READ = encode_packet({"Command": "FRC_ReadJointAngles"})


def _fanuc_cell(moving: bool) -> Iterator[Fanuc]:
    """Emulated cell (robot held, or always moving) with its EMULATED RMI."""
    robot = {"move_time_s": 1.0, "dwell_s": 0.0} if moving else {}
    sim = start_emulated_cell(hold=not moving, seed=11, robot=robot)
    try:
        assert sim.runner is not None
        face = sim.runner.faces["robot_fanuc_rmi"]
        assert isinstance(face, FanucRmiServer)
        assert host_port(sim.ready["robot_fanuc_rmi"]) == (face.host, face.port)
        yield sim, face
    finally:
        sim.stop()


@pytest.fixture
def fanuc() -> Iterator[Fanuc]:
    yield from _fanuc_cell(moving=False)


@pytest.fixture
def fanuc_moving() -> Iterator[Fanuc]:
    yield from _fanuc_cell(moving=True)


def _driver(face: FanucRmiServer, **cfg: object) -> FanucRmiRobot:
    return FanucRmiRobot(FanucRmiConfig.model_validate({"port": face.port, **cfg}))


def _joint_reply(q: list[float], **extra: object) -> bytes:
    angles = {f"J{i + 1}": v for i, v in enumerate(q)} | {"J7": 0.0, "J8": 0.0, "J9": 0.0}
    packet = {"Command": "FRC_ReadJointAngles", "ErrorID": 0, "TimeTag": 7, "JointAngle": angles}
    return encode_packet(packet | extra)


# --------------------------------------------------------------------------- packets
def test_packets_as_the_manual_states_them() -> None:
    assert encode_packet({"Communication": "FRC_Connect"}) == b'{"Communication":"FRC_Connect"}\r\n'
    with pytest.raises(ValueError, match="first key"):
        encode_packet({"ErrorID": 0, "Command": "FRC_Abort"})
    with pytest.raises(ValueError, match="first key"):
        decode_packet(b'{"ErrorID": 0, "Command": "FRC_Abort"}\r\n')
    with pytest.raises(ValueError, match="NaN"):
        decode_packet(b'{"Command": "FRC_ReadJointAngles", "J1": NaN}\r\n')
    q = [1.5, -90.0, 90.0, 0.0, 45.25, 12.0]
    assert joint_angles(decode_packet(_joint_reply(q))) == tuple(q)
    bad = {"Command": "FRC_ReadJointAngles", "ErrorID": 0, "JointAngle": {"J1": 1.0}}
    with pytest.raises(ValueError, match=r"JointAngle\.J2: expected a number, got None"):
        joint_angles(bad)
    bad["JointAngle"] = {f"J{i}": (True if i == 3 else 0.0) for i in range(1, 7)}
    with pytest.raises(ValueError, match=r"JointAngle\.J3"):
        joint_angles(bad)


# --------------------------------------------------------------------------- cross-check
def test_fanuc_rmi_client_reads_the_emulated_truth(fanuc: Fanuc, tmp_path: Path) -> None:
    """The public client connects (FRC_Connect, session port), initializes, reads the joints
    and disconnects; J1..J6 agree with the cell's truth to 0.01 deg."""
    sim, face = fanuc
    truth = np.asarray(sim.control("state")["joints_deg"])
    client = RobotClient(
        host="127.0.0.1",
        startup_port=face.port,
        main_port=face.session.port,
        connect_timeout=2.0,
        socket_timeout=2.0,
        reader_timeout=2.0,
        attempts=1,
        startup_pause=0.0,
    )
    client.connect()
    try:
        client.initialize(uframe=0, utool=1)
        reply = client.read_joint_coordinates(output_path=str(tmp_path / "joints.jsonl"))
    finally:
        client.close()
    assert reply["ErrorID"] == 0
    got = np.asarray([reply["JointAngle"][f"J{i}"] for i in range(1, 7)])
    assert np.abs(got - truth).max() <= 0.01
    logged = json.loads((tmp_path / "joints.jsonl").read_text().splitlines()[0])
    assert logged["JointAngle"] == reply["JointAngle"]


# --------------------------------------------------------------------------- our driver
async def test_one_session_at_a_time(fanuc: Fanuc) -> None:
    """A second FRC_Connect while a session is open gets RMIT-026 (a RobotLinkDown naming
    it); after the first disconnects, the second connects."""
    _, face = fanuc
    first, second = _driver(face), _driver(face, name="second")
    try:
        await first.read_joints()
        with pytest.raises(RobotLinkDown, match="RMIT-026 Robot is Already Connected"):
            await second.connect()
        await first.close()
        await asyncio.sleep(0.05)
        await second.connect()
        await second.read_joints()
    finally:
        await first.close()
        await second.close()
    assert RMIT_ALREADY_CONNECTED == 2556954


async def test_driver_reads_the_truth_through_drops_and_late_replies(fanuc: Fanuc) -> None:
    sim, face = fanuc
    await drops_and_late_replies(sim, _driver(face), RESOLUTION_DEG)


async def test_late_replies_are_never_taken_for_the_retry(fanuc_moving: Fanuc) -> None:
    sim, face = fanuc_moving
    robot = _driver(face)
    await late_replies_never_taken(sim, robot, RESOLUTION_DEG)
    assert robot.late_discarded >= 2


async def test_link_down_then_back(fanuc: Fanuc) -> None:
    sim, face = fanuc
    robot = _driver(face, timeout_s=0.2, fast_reply_timeout_s=0.1)
    await link_down_then_back(sim, robot, "robot_fanuc_rmi", RESOLUTION_DEG)


async def test_frozen_joints_raise_stale(fanuc: Fanuc) -> None:
    sim, face = fanuc
    await frozen_joints_raise_stale(sim, _driver(face, max_unchanged_s=0.2))


async def test_invalid_group_is_a_protocol_error_with_its_code(fanuc: Fanuc) -> None:
    _, face = fanuc
    robot = _driver(face, group=2)
    try:
        with pytest.raises(RobotProtocolError, match="RMIT-039 Invalid Group Number") as info:
            await robot.read_joints()
    finally:
        await robot.close()
    assert info.value.code == 2556967


async def test_scripted_session_skips_unsolicited_packets_and_checks_replies() -> None:
    """Scripted controller: FRC_Connect on the connect port, then on the session port a
    system-fault packet before the joint reply (noted, skipped), a reply lacking J6, and
    FRC_Disconnect on close."""
    q = [10.0, -20.0, 30.0, -40.0, 50.0, -60.0]
    fault = encode_packet({"Communication": "FRC_SystemFault", "SequenceID": 4})
    missing = json.loads(_joint_reply(q))
    del missing["JointAngle"]["J6"]
    bye = {"Communication": "FRC_Disconnect"}
    session = [
        (READ, fault + _joint_reply(q)),
        (READ, encode_packet(missing)),
        (encode_packet(bye), encode_packet(bye | {"ErrorID": 0})),
    ]
    async with expected_protocol_tcp(session) as session_port:
        reply = {
            "Communication": "FRC_Connect",
            "ErrorID": 0,
            "PortNumber": session_port,
            "MajorVersion": 7,
            "MinorVersion": 0,
        }
        hello = [(encode_packet({"Communication": "FRC_Connect"}), encode_packet(reply))]
        async with expected_protocol_tcp(hello) as port:
            robot = FanucRmiRobot(FanucRmiConfig(port=port, retries=0))
            try:
                assert (await robot.read_joints()).joints_deg == tuple(q)
                assert robot.system_faults == [4]
                with pytest.raises(RobotProtocolError, match=r"JointAngle\.J6"):
                    await robot.read_joints()
            finally:
                await robot.close()


async def test_unreadable_packet_closes_the_session_and_the_next_read_reopens(
    fanuc: Fanuc,
) -> None:
    """A reply that is not JSON cannot be attributed: RobotProtocolError, session closed;
    the next read opens a new session (FRC_Connect again) and reads the truth."""
    sim, face = fanuc
    robot = _driver(face)
    try:
        await robot.read_joints()
        # Make the next line the driver reads unreadable (as if garbled on the wire).
        assert robot._reader is not None
        robot._reader.feed_data(b"{not json\r\n")
        with pytest.raises(RobotProtocolError, match="unreadable RMI packet"):
            await robot.read_joints()
        assert not robot.connected
        await asyncio.sleep(0.15)  # the back-off after a reset (reconnect_min_s 0.1 s)
        reading = await robot.read_joints()
    finally:
        await robot.close()
    truth = np.asarray(sim.control("state")["joints_deg"])
    assert np.abs(np.asarray(reading.joints_deg) - truth).max() <= RESOLUTION_DEG
    assert robot.connects == 2


async def test_refused_marker_is_not_taken_for_synchronisation() -> None:
    """Scripted controller: the joint request goes unanswered; the marker is refused with
    RMIT-027 (Wait for Command Done) *before* the late joint reply arrives; only the second,
    accepted marker re-synchronises, and the value returned is the new reply's, never the
    late one's."""
    old, new = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0], [11.0, 12.0, 13.0, 14.0, 15.0, 16.0]
    marker = encode_packet({"Command": "FRC_GetStatus"})
    refused = encode_packet({"Command": "FRC_GetStatus", "ErrorID": 2556955})
    accepted = encode_packet({"Command": "FRC_GetStatus", "ErrorID": 0, "ServoReady": 1})
    bye = {"Communication": "FRC_Disconnect"}
    session = [
        (READ, b""),  # silent: the driver retries after fast_reply_timeout_s
        (marker, refused + _joint_reply(old)),
        (marker, accepted),
        (READ, _joint_reply(new)),
        (encode_packet(bye), encode_packet(bye | {"ErrorID": 0})),
    ]
    async with expected_protocol_tcp(session) as session_port:
        hello_reply = {"Communication": "FRC_Connect", "ErrorID": 0, "PortNumber": session_port}
        hello = [(encode_packet({"Communication": "FRC_Connect"}), encode_packet(hello_reply))]
        async with expected_protocol_tcp(hello) as port:
            cfg = FanucRmiConfig(port=port, retries=1, fast_reply_timeout_s=0.1, timeout_s=2.0)
            robot = FanucRmiRobot(cfg)
            try:
                assert (await robot.read_joints()).joints_deg == tuple(new)
                assert robot.late_discarded == 1
                assert robot.attempts.recovered_total == 1
            finally:
                await robot.close()
