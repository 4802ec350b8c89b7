"""Golden-byte tests: every frame the drivers send and parse, PyMeasure expected_protocol
style (a scripted device over a real pty or loopback TCP fails on any byte difference)."""

from __future__ import annotations

import math
import time

import pytest
from expected_protocol import ProtocolMismatch, expected_protocol_pty, expected_protocol_tcp
from pymodbus.framer import FramerRTU

from drivers import (
    HuashuConfig,
    HuashuSocketCmdRobot,
    IndicatorConfig,
    IndicatorCRCError,
    IndicatorNoReply,
    IndicatorOverRange,
    IndicatorProtocolError,
    ModbusIndicator,
    ModbusRobotConfig,
    ModbusTcpRobot,
    RobotProtocolError,
    make_indicator,
    make_robot,
)
from drivers.ascii_indicator import parse_ascii_frame
from drivers.huashu import decode_reply, encode_request, parse_float_list
from drivers.modbus_robot import UR_PRESET, decode_joints_deg
from drivers.wire_bytes import (
    add_crc,
    crc16_modbus,
    int32_to_words,
    parse_rtu_read_response,
    rtu_read_request,
    rtu_write_coil_request,
    rtu_write_multiple_request,
    rtu_write_single_request,
    words_to_int32,
)
from simulator.wire import ascii_frame

H = bytes.fromhex
pytestmark = pytest.mark.anyio

# --------------------------------------------------------------------------- pure frames


def test_crc_of_the_textbook_frame() -> None:
    # The Modbus spec's example request "01 03 00 00 00 0A" carries CRC C5 CD.
    assert add_crc(H("01 03 00 00 00 0a")) == H("01 03 00 00 00 0a c5 cd")
    assert crc16_modbus(b"123456789") == 0x4B37  # CRC-16/MODBUS check value


@pytest.mark.parametrize(
    "frame",
    [
        rtu_read_request(1, 3, 0, 8),
        rtu_read_request(17, 4, 0x0100, 3),
        rtu_write_single_request(1, 0x10, 1),
        rtu_write_multiple_request(1, 0, [0, 0]),
        rtu_write_coil_request(1, 0, True),
    ],
)
def test_our_crc_agrees_with_pymodbus(frame: bytes) -> None:
    assert FramerRTU.compute_CRC(frame[:-2]) == int.from_bytes(frame[-2:], "big")


def test_golden_requests() -> None:
    assert rtu_read_request(1, 3, 0, 8) == H("01 03 00 00 00 08 44 0c")
    assert rtu_write_single_request(1, 0x0010, 1) == H("01 06 00 10 00 01 49 cf")
    assert rtu_write_coil_request(1, 0, True) == H("01 05 00 00 ff 00 8c 3a")
    assert rtu_write_multiple_request(1, 0, [0, 0]) == H("01 10 00 00 00 02 04 00 00 00 00 f3 af")


def test_read_response_decoding_and_rejections() -> None:
    frame = add_crc(H("01 03 04 00 02 08 87"))
    assert parse_rtu_read_response(frame, 1, 3, 2) == [0x0002, 0x0887]
    bad = bytearray(frame)
    bad[4] ^= 0x01
    with pytest.raises(ValueError, match="CRC"):
        parse_rtu_read_response(bytes(bad), 1, 3, 2)
    with pytest.raises(ValueError, match="exception code 2"):
        parse_rtu_read_response(add_crc(H("01 83 02")), 1, 3, 2)
    with pytest.raises(ValueError, match="length"):
        parse_rtu_read_response(frame[:-1], 1, 3, 2)


@pytest.mark.parametrize("value", [0, 1, 133255, -1, -199999, 999999, 2**31 - 1, -(2**31)])
@pytest.mark.parametrize("order", ["ABCD", "CDAB"])
def test_int32_word_orders_round_trip(value: int, order: str) -> None:
    assert words_to_int32(int32_to_words(value, order), order) == value


def test_word_order_golden() -> None:
    assert int32_to_words(133255, "ABCD") == [0x0002, 0x0887]
    assert int32_to_words(133255, "CDAB") == [0x0887, 0x0002]
    assert words_to_int32([0xFFFF, 0xFFFE], "ABCD") == -2


def test_huashu_frames() -> None:
    assert encode_request(7, "mot.getJntData(0)") == b"i:7,c:mot.getJntData(0)@hs@"
    assert decode_reply(b"i:7,e:0,d:{1.5,-2,3,4,5,6,}@hs@") == (7, 0, "{1.5,-2,3,4,5,6,}")
    assert decode_reply(b"i:-1,e:1003,d:servo alarm@hs@") == (-1, 1003, "servo alarm")
    assert parse_float_list("{1.5,-2,3,4,5,6,}") == [1.5, -2.0, 3.0, 4.0, 5.0, 6.0]
    with pytest.raises(ValueError):
        decode_reply(b"garbage@hs@")
    with pytest.raises(ValueError):
        parse_float_list("{1,abc,}")


def test_ur_register_decoding() -> None:
    # -0.5 rad: one negative turn (65535) and 2π-0.5 rad in the angle register.
    reg = round((2 * math.pi - 0.5) * 1000)
    q = decode_joints_deg([reg, 0, 1000, 0, 0, 0], [65535, 0, 0, 1, 0, 0], UR_PRESET)
    assert q[0] == pytest.approx(math.degrees(-0.5), abs=0.03)
    assert q[2] == pytest.approx(math.degrees(1.0))
    assert q[3] == pytest.approx(360.0)


def test_ascii_frame_golden() -> None:
    frame = ascii_frame(133255, 2, 4)
    assert frame == b"\x02+1332.554" + f"{sum(b'+1332.554') & 0xFF:02X}".encode() + b"\r\n"
    assert parse_ascii_frame(frame) == (133255, 2, 4)
    assert parse_ascii_frame(ascii_frame(-1250, 2, 0)) == (-1250, 2, 0)
    broken = frame.replace(b"1332", b"1333")
    with pytest.raises(ValueError, match="checksum"):
        parse_ascii_frame(broken)


# --------------------------------------------------------------------------- drivers on a pty

READ = H("01 03 00 00 00 08 44 0c")


def _reply(value: int, decimals: int = 2, status: int = 0) -> bytes:
    regs = [*int32_to_words(value, "ABCD"), decimals, 0, 0, 0, 0, status]
    return add_crc(H("01 03 10") + b"".join(r.to_bytes(2, "big") for r in regs))


def _indicator(port: str, **kw: object) -> ModbusIndicator:
    cfg = {"port": port, "baud": 115200, "timeout_s": 0.2, "retries": 0, **kw}
    driver = make_indicator(cfg)
    assert isinstance(driver, ModbusIndicator)
    return driver


async def test_indicator_read_exact_bytes() -> None:
    async with expected_protocol_pty([(READ, _reply(133255, 2, 0b100))]) as port:
        ind = _indicator(port)
        reading = await ind.read()
        await ind.close()
    assert reading.length_mm == pytest.approx(1332.55)
    assert reading.counts == 133255 and reading.decimals == 2
    assert reading.moving and not reading.over_range


async def test_indicator_cdab_fc04_fixed_decimals() -> None:
    request = rtu_read_request(5, 4, 0x0100, 2)
    regs = int32_to_words(-4200, "CDAB")
    reply = add_crc(H("05 04 04") + b"".join(r.to_bytes(2, "big") for r in regs))
    regmap = {
        "value_address": 0x0100,
        "word_order": "CDAB",
        "read_function": 4,
        "decimals_address": None,
        "status_address": None,
    }
    async with expected_protocol_pty([(request, reply)]) as port:
        ind = _indicator(port, device_id=5, registers=regmap, decimals=3)
        reading = await ind.read()
        await ind.close()
    assert reading.length_mm == pytest.approx(-4.2)
    assert reading.status == 0


@pytest.mark.parametrize(
    ("strategy", "request_hex", "reply_hex"),
    [
        ("command", "01 06 00 10 00 01 49 cf", "01 06 00 10 00 01 49 cf"),
        ("coil", "01 05 00 00 ff 00 8c 3a", "01 05 00 00 ff 00 8c 3a"),
        ("write_zero", "01 10 00 00 00 02 04 00 00 00 00 f3 af", None),
    ],
)
async def test_indicator_zero_strategies(
    strategy: str, request_hex: str, reply_hex: str | None
) -> None:
    reply = add_crc(H("01 10 00 00 00 02")) if reply_hex is None else H(reply_hex)
    async with expected_protocol_pty([(H(request_hex), reply)]) as port:
        ind = _indicator(port, zero_strategy=strategy)
        await ind.zero()
        await ind.close()


async def test_indicator_crc_error_is_typed_and_carries_frames() -> None:
    bad = bytearray(_reply(133255))
    bad[5] ^= 0x40
    async with expected_protocol_pty([(READ, bytes(bad))]) as port:
        ind = _indicator(port, quiet_s=0.05)
        with pytest.raises(IndicatorCRCError) as info:
            await ind.read()
        await ind.close()
    assert info.value.device == "indicator"
    assert any("tx 01 03 00 00 00 08 44 0c" in f for f in info.value.frames_hex)
    assert any(bytes(bad).hex(" ") in f for f in info.value.frames_hex)


@pytest.mark.parametrize(
    ("pos", "flip"),
    [(5, 0x40), (2, 0x01), (1, 0x80), (19, 0x01)],
    ids=["data", "byte-count", "exception-bit", "crc"],
)
async def test_indicator_corrupted_reply_is_retried_without_waiting_for_the_timeout(
    pos: int, flip: int
) -> None:
    """pymodbus drops a corrupted frame and would wait out ``timeout_s`` (a longer byte
    count even makes it wait for bytes that never come); the whole reply is on the line, so
    the driver retries as soon as the line has been quiet for a frame gap."""
    bad = bytearray(_reply(133255))
    bad[pos] ^= flip
    async with expected_protocol_pty([(READ, bytes(bad)), (READ, _reply(4242))]) as port:
        ind = _indicator(port, retries=1, timeout_s=1.0)
        t0 = time.monotonic()
        reading = await ind.read()
        took = time.monotonic() - t0
        await ind.close()
    assert reading.counts == 4242
    assert took < 0.5, took  # timeout_s + quiet_s = 2 s before


async def test_indicator_reply_from_another_device_is_a_protocol_error() -> None:
    other = bytearray(_reply(133255))
    other[0] = 2
    async with expected_protocol_pty([(READ, add_crc(bytes(other[:-2])))]) as port:
        ind = _indicator(port, retries=1, timeout_s=1.0)
        t0 = time.monotonic()
        with pytest.raises(IndicatorProtocolError, match="not accepted"):
            await ind.read()
        took = time.monotonic() - t0
        await ind.close()
    assert took < 0.5, took


async def test_indicator_no_reply_then_retry_succeeds() -> None:
    async with expected_protocol_pty([(READ, b""), (READ, _reply(100))]) as port:
        ind = _indicator(port, retries=1, quiet_s=0.02)
        reading = await ind.read()
        await ind.close()
    assert reading.counts == 100


async def test_indicator_no_reply_raises() -> None:
    async with expected_protocol_pty([(READ, b"")]) as port:
        ind = _indicator(port, quiet_s=0.02)
        with pytest.raises(IndicatorNoReply):
            await ind.read()
        await ind.close()


async def test_indicator_exception_response() -> None:
    async with expected_protocol_pty([(READ, add_crc(H("01 83 02")))]) as port:
        ind = _indicator(port)
        with pytest.raises(IndicatorProtocolError, match="exception code 2"):
            await ind.read()
        await ind.close()


async def test_indicator_over_range_policies() -> None:
    async with expected_protocol_pty([(READ, _reply(200000, 2, 0b001))] * 2) as port:
        ind = _indicator(port)
        with pytest.raises(IndicatorOverRange):
            await ind.read()
        ind.config.over_range_policy = "flag"
        reading = await ind.read()
        await ind.close()
    assert reading.over_range


async def test_expected_protocol_detects_wrong_bytes() -> None:
    """The harness itself fails when the driver sends something else."""
    with pytest.raises(ProtocolMismatch):
        async with expected_protocol_pty([(rtu_read_request(1, 3, 0, 9), b"")]) as port:
            ind = _indicator(port, quiet_s=0.01)
            with pytest.raises(IndicatorNoReply):
                await ind.read()
            await ind.close()


# --------------------------------------------------------------------------- robots on TCP


async def test_huashu_exact_bytes_with_alarm_and_late_reply() -> None:
    exchanges = [
        (
            b"i:1,c:mot.getJntData(0)@hs@",
            b"i:-1,e:1003,d:servo alarm@hs@"  # unsolicited alarm first
            b"i:0,e:0,d:{9,9,9,9,9,9,}@hs@"  # a reply to an older request: ignored
            b"i:1,e:0,d:{10.5,-20.25,30,40,50,60.125,}@hs@",
        ),
        (b"i:2,c:mot.getJntData(0)@hs@", b"i:2,e:5,d:not ready@hs@"),
    ]
    async with expected_protocol_tcp(exchanges) as port:
        robot = make_robot({"kind": "huashu-socketcmd", "port": port, "timeout_s": 1.0})
        assert isinstance(robot, HuashuSocketCmdRobot)
        reading = await robot.read_joints()
        with pytest.raises(RobotProtocolError) as info:
            await robot.read_joints()
        await robot.close()
    assert reading.joints_deg == (10.5, -20.25, 30.0, 40.0, 50.0, 60.125)
    assert info.value.code == 5
    assert [(a.code, a.text) for a in robot.alarms] == [(1003, "servo alarm")]


async def test_modbus_robot_exact_bytes_ur_preset() -> None:
    # One block read 270..325 (56 registers), transaction id 1, unit 1.
    request = H("00 01 00 00 00 06 01 03 01 0e 00 38")
    regs = [0] * 56
    regs[0:6] = [round((2 * math.pi - 0.5) * 1000), 1000, 0, 0, 0, 0]
    regs[50:56] = [0xFFFF, 0, 1, 0, 0, 0]
    pdu = H("03 70") + b"".join(r.to_bytes(2, "big") for r in regs)
    reply = H("00 01 00 00") + (len(pdu) + 1).to_bytes(2, "big") + H("01") + pdu
    async with expected_protocol_tcp([(request, reply)]) as port:
        robot = ModbusTcpRobot(ModbusRobotConfig(port=port))
        reading = await robot.read_joints()
        await robot.close()
    assert reading.joints_deg[0] == pytest.approx(math.degrees(-0.5), abs=0.03)
    assert reading.joints_deg[1] == pytest.approx(math.degrees(1.0))
    assert reading.joints_deg[2] == pytest.approx(360.0)


def test_factories_reject_bad_config() -> None:
    with pytest.raises(ValueError):
        make_robot({"kind": "kuka"})
    with pytest.raises(ValueError):
        make_indicator({"baud": 12})
    with pytest.raises(ValueError):
        IndicatorConfig(decimals=None, registers={"decimals_address": None})  # type: ignore[arg-type]
    assert isinstance(make_robot(HuashuConfig()), HuashuSocketCmdRobot)


async def test_manual_robot() -> None:
    from drivers import ManualRobot, RobotNoData

    robot = make_robot({"kind": "manual"})
    assert isinstance(robot, ManualRobot)
    with pytest.raises(RobotNoData):
        await robot.read_joints()
    robot.submit([1, 2, 3, 4, 5, 6])
    assert (await robot.read_joints()).joints_deg == (1.0, 2.0, 3.0, 4.0, 5.0, 6.0)
    with pytest.raises(RobotProtocolError):
        robot.submit([1, 2, 3])
