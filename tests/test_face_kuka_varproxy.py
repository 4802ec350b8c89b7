"""KUKA through KukaVarProxy: frames against the public client and the proxy's source, the
strict E6AXIS parser, the EMULATED proxy read by py_openshowvar (a client no one here wrote),
and our driver against the emulated proxy with faults (drops, late replies, link down,
frozen joints): no corrupt value is ever returned, every failure is a typed error.
"""

from __future__ import annotations

import socket
from collections.abc import Iterator

import numpy as np
import pytest
from expected_protocol import expected_protocol_tcp
from helpers import host_port, start_emulated_cell
from py_openshowvar import openshowvar
from robot_faces import (
    drops_and_late_replies,
    frozen_joints_raise_stale,
    late_replies_never_taken,
    link_down_then_back,
)

from drivers.errors import RobotProtocolError
from drivers.kuka_varproxy import (
    KukaVarProxyConfig,
    KukaVarProxyRobot,
    decode_reply,
    encode_read,
    encode_reply,
    encode_write,
    format_e6axis,
    parse_e6axis,
)
from simulator.faces.kuka_varproxy import KukaVarProxyServer
from simulator.runner import SimulatorThread

pytestmark = pytest.mark.anyio
#: |reading - truth| of a held robot [deg]: KRL prints a REAL to 7 significant digits.
RESOLUTION_DEG = 2e-4
AXIS = "{E6AXIS: A1 1.5, A2 -90.0, A3 90.0, A4 0.0, A5 45.25, A6 -1.234560E-05}"


Kuka = tuple[SimulatorThread, KukaVarProxyServer]


def _kuka_cell(moving: bool) -> Iterator[Kuka]:
    """Emulated cell (robot held, or always moving) with its EMULATED KukaVarProxy."""
    robot = {"move_time_s": 1.0, "dwell_s": 0.0} if moving else {}
    sim = start_emulated_cell(hold=not moving, seed=11, robot=robot)
    try:
        assert sim.runner is not None
        face = sim.runner.faces["robot_kuka_varproxy"]
        assert isinstance(face, KukaVarProxyServer)
        assert host_port(sim.ready["robot_kuka_varproxy"]) == (face.host, face.port)
        yield sim, face
    finally:
        sim.stop()


@pytest.fixture
def kuka() -> Iterator[Kuka]:
    yield from _kuka_cell(moving=False)


@pytest.fixture
def kuka_moving() -> Iterator[Kuka]:
    yield from _kuka_cell(moving=True)


def _driver(face: KukaVarProxyServer, **cfg: object) -> KukaVarProxyRobot:
    return KukaVarProxyRobot(KukaVarProxyConfig.model_validate({"port": face.port, **cfg}))


# --------------------------------------------------------------------------- frames
def test_requests_are_byte_identical_to_py_openshowvar() -> None:
    client = openshowvar.__new__(openshowvar)  # the packers only, no socket
    client.msg_id, client.varname, client.value = 513, b"$AXIS_ACT", b"75"
    assert encode_read(513, "$AXIS_ACT") == client._pack_read_req()
    assert encode_write(513, "$AXIS_ACT", "75") == client._pack_write_req()
    assert encode_read(513, "$OV_PRO").hex(" ") == "02 01 00 0a 00 00 07 24 4f 56 5f 50 52 4f"


def test_reply_layout_of_the_proxy_source() -> None:
    """readMsg: id, length counting the tail, function, value_len, value, 00 01 status."""
    frame = bytes.fromhex("0030 0009 00 0003 313030 000101")
    assert encode_reply(0x30, 0, b"100", True) == frame
    reply = decode_reply(frame)
    assert (reply.msg_id, reply.function, reply.value, reply.ok) == (0x30, 0, b"100", True)
    # py_openshowvar's README shows a build whose length leaves the tail out: accepted.
    assert decode_reply(bytes.fromhex("0030 0006 00 0003 313030 000101")).value == b"100"
    assert not decode_reply(bytes.fromhex("0030 0006 00 0000 000100")).ok
    for bad, word in [
        ("0030 0007 00 0003 313030 000101", "length field 7"),
        ("0030 0009 00 0003 313030 000201", "tail"),
        ("0030 0009 00 0003 313030 000102", "tail"),
        ("0030 0009 00 0004 313030 000101", "value_len 4"),
    ]:
        with pytest.raises(ValueError, match=word):
            decode_reply(bytes.fromhex(bad))


def test_e6axis_is_parsed_strictly() -> None:
    assert parse_e6axis(AXIS) == (1.5, -90.0, 90.0, 0.0, 45.25, -1.23456e-05)
    q = (39.2309379, -60.999, 299.3303846, -163.484, 0.0, 1e-7)
    assert np.allclose(parse_e6axis(format_e6axis(q)), q, atol=1e-4, rtol=0)
    for bad, word in [
        ("{E6POS: X 1.0, Y 2.0}", "type E6POS"),
        ("E6AXIS: A1 1.0", "not a KRL struct"),
        ("{E6AXIS: A1 1.0, A2 2.0, A3 3.0, A4 4.0, A5 5.0}", "lacks A6"),
        ("{E6AXIS: A1 1, A1 2, A2 0, A3 0, A4 0, A5 0, A6 0}", "A1 appears twice"),
        ("{E6AXIS: A1 1.2.3, A2 0, A3 0, A4 0, A5 0, A6 0}", "'A1 1.2.3'"),
        ("{E6AXIS: A1 nan, A2 0, A3 0, A4 0, A5 0, A6 0}", "'A1 nan'"),
        ("{E6AXIS: A1 0, A2 0, A3 0, A4 0, A5 0, A6 0, B1 0}", "unknown component B1"),
        ("{E6AXIS: A1 0, A2 0, A3 0, A4 0, A5 0, A6 0,}", "component ''"),
    ]:
        with pytest.raises(ValueError, match=word):
            parse_e6axis(bad)


# --------------------------------------------------------------------------- cross-check
def test_py_openshowvar_reads_the_emulated_truth(
    kuka: Kuka,
) -> None:
    """The public client reads $AXIS_ACT from the EMULATED proxy and agrees with the cell's
    truth to 0.01 deg; it also reads and writes $OV_PRO, and an unknown variable is empty."""
    sim, face = kuka
    truth = np.asarray(sim.control("state")["joints_deg"])
    client = openshowvar("127.0.0.1", face.port)
    try:
        value = client.read("$AXIS_ACT", debug=False)
        assert client.write("$OV_PRO", "40", debug=False) == b"40"
        assert client.read("$OV_PRO", debug=False) == b"40"
        assert client.read("$NO_SUCH_VAR", debug=False) == b""
    finally:
        client.close()
    assert isinstance(value, bytes) and value.startswith(b"{E6AXIS: A1 ")
    assert np.abs(np.asarray(parse_e6axis(value.decode())) - truth).max() <= 0.01


# --------------------------------------------------------------------------- our driver
async def test_driver_reads_the_truth_through_drops_and_late_replies(kuka: Kuka) -> None:
    sim, face = kuka
    await drops_and_late_replies(sim, _driver(face), RESOLUTION_DEG)


async def test_late_replies_are_never_taken_for_the_retry(kuka_moving: Kuka) -> None:
    sim, face = kuka_moving
    robot = _driver(face)
    await late_replies_never_taken(sim, robot, RESOLUTION_DEG)


async def test_link_down_then_back(kuka: Kuka) -> None:
    sim, face = kuka
    robot = _driver(face, timeout_s=0.2, fast_reply_timeout_s=0.1)
    await link_down_then_back(sim, robot, "robot_kuka_varproxy", RESOLUTION_DEG)


async def test_frozen_joints_raise_stale(kuka: Kuka) -> None:
    sim, face = kuka
    await frozen_joints_raise_stale(sim, _driver(face, max_unchanged_s=0.2))


async def test_unknown_variable_is_an_error(
    kuka: Kuka,
) -> None:
    _, face = kuka
    robot = _driver(face, variable="$NO_SUCH_VAR")
    try:
        with pytest.raises(RobotProtocolError, match=r"\$NO_SUCH_VAR: empty value"):
            await robot.read_joints()
    finally:
        await robot.close()


@pytest.mark.parametrize(
    ("value", "ok", "word"),
    [
        (AXIS.replace(", A6 -1.234560E-05", ""), True, "lacks A6"),
        ("{E6AXIS: A1 x, A2 0, A3 0, A4 0, A5 0, A6 0}", True, "'A1 x'"),
        (AXIS, False, "failed read"),
    ],
)
async def test_bad_replies_are_protocol_errors(value: str, ok: bool, word: str) -> None:
    """Scripted proxy: the exact request bytes, then a malformed or failed reply."""
    request = encode_read(1, "$AXIS_ACT")
    reply = encode_reply(1, 0, value.encode(), ok)
    async with expected_protocol_tcp([(request, reply)]) as port:
        robot = KukaVarProxyRobot(KukaVarProxyConfig(port=port, retries=0))
        try:
            with pytest.raises(RobotProtocolError, match=word) as info:
                await robot.read_joints()
        finally:
            await robot.close()
    assert "$AXIS_ACT" in str(info.value)


async def test_late_reply_is_skipped_and_a_broken_frame_resets_the_link() -> None:
    """Scripted proxy: a reply to an older id before the awaited one is skipped (counted);
    then a frame with a broken tail is a protocol error that closes the connection (the
    stream cannot be trusted), and the next read opens a new one."""
    q = "{E6AXIS: A1 1.0, A2 2.0, A3 3.0, A4 4.0, A5 5.0, A6 6.0}"
    broken = bytearray(encode_reply(2, 0, q.encode(), True))
    broken[-2] = 0x07  # tail 00 07 01
    script = [
        (
            encode_read(1, "$AXIS_ACT"),
            encode_reply(0, 0, b"{stale}", True) + encode_reply(1, 0, q.encode(), True),
        ),
        (encode_read(2, "$AXIS_ACT"), bytes(broken)),
    ]
    async with expected_protocol_tcp(script) as port:
        robot = KukaVarProxyRobot(KukaVarProxyConfig(port=port, retries=0))
        try:
            assert (await robot.read_joints()).joints_deg == (1.0, 2.0, 3.0, 4.0, 5.0, 6.0)
            assert robot.late_discarded == 1
            with pytest.raises(RobotProtocolError, match="tail 00 07 01"):
                await robot.read_joints()
            assert not robot.connected
        finally:
            await robot.close()


def test_face_answers_pipelined_requests_in_order(kuka: Kuka) -> None:
    """Two requests in one TCP segment (the proxy splits them): two replies, ids echoed."""
    _, face = kuka
    with socket.create_connection((face.host, face.port), timeout=2) as sock:
        sock.sendall(encode_read(7, "$OV_PRO") + encode_read(8, "PING"))
        data = b""
        while len(data) < 13 + 14:  # "100" and "PONG" replies
            data += sock.recv(256)
    first, second = decode_reply(data[:13]), decode_reply(data[13:])
    assert (first.msg_id, first.value, second.msg_id, second.value) == (7, b"100", 8, b"PONG")
