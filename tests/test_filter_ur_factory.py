"""A UR's factory calibration as the filter's nominal model: calibration.conf deltas and the
primary interface's KinematicsInfo (calib/robots/ur_factory.py, drivers/ur_primary.py).

The calibration.conf below is written by this project in the file's shape (section
``[mounting]``, ``delta_*`` lists in rad and m, comments, other keys and sections); the
KinematicsInfo stream is built byte by byte in the primary interface's layout.
"""

from __future__ import annotations

import asyncio
import struct
import tomllib
from pathlib import Path

import numpy as np
import pytest

from calib.filter.correct import Calibration
from calib.filter.kin import flange_frames
from calib.filter.run import filter_files
from calib.models import RobotModel, model_from_mapping
from calib.robots.ur_factory import (
    FactoryCalibrationError,
    from_kinematics_info,
    main,
    parse_calibration_conf,
    with_deltas,
)
from drivers.ur_primary import (
    PrimaryInterfaceError,
    kinematics_info_in,
    read_kinematics_info,
)

LIBRARY = Path(__file__).resolve().parent.parent / "calib" / "robots" / "library"

CONF = """\
# written by the controller
[mounting]
delta_theta = [ 2.1e-05, -0.000312, 0.000455, -0.000131, 1.7e-05, -3.3e-05]  # rad
delta_a = [ 4.2e-05, 0.000391, -0.000287, 3.1e-05, -2.2e-05, 0]
delta_d = [ 0.000118, 0.00021, -0.000305, 0.000151, -7.7e-05, 0.000133]
delta_alpha = [ -0.000217, 0.000134, -0.000402, 0.000299, -0.000187, 0]
joint_checksum = [ 111, 222, 333, 444, 555, 666]
calibration_status = 2 # linearised

[other]
delta_a = [ 1, 1, 1, 1, 1, 1]
"""


def _ur5e() -> RobotModel:
    return model_from_mapping(tomllib.loads((LIBRARY / "ur5e.toml").read_text("utf-8")))


def test_calibration_conf_deltas_are_added_to_the_published_table() -> None:
    base = _ur5e()
    deltas = parse_calibration_conf(CONF)
    arm = with_deltas(base, deltas)
    assert arm.name == "ur5e-factory" and arm.controller == base.controller
    diff = arm.dh_table - base.dh_table
    np.testing.assert_allclose(diff[:, 1], 1000.0 * np.array(deltas.a_m), atol=1e-12)
    np.testing.assert_allclose(diff[:, 2], 1000.0 * np.array(deltas.d_m), atol=1e-12)
    np.testing.assert_allclose(np.deg2rad(diff[:, 0]), deltas.alpha_rad, atol=1e-15)
    np.testing.assert_allclose(np.deg2rad(diff[:, 3]), deltas.theta_rad, atol=1e-15)
    # The [other] section's delta_a is not the mounting's.
    assert deltas.a_m[0] == pytest.approx(4.2e-05)
    # The deltas move the flange by a UR's factory-calibration size (about a millimetre).
    q = np.random.default_rng(1).uniform(-170.0, 170.0, (200, 6))
    gap = np.linalg.norm(flange_frames(arm, q)[:, :3, 3] - flange_frames(base, q)[:, :3, 3], axis=1)
    assert 0.1 < np.median(gap) < 3.0


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("[mounting]\ndelta_theta = [0,0,0,0,0,0]\n", "calibration.conf: [mounting] has no"),
        (
            CONF.replace("delta_d = [ 0.000118,", "delta_d = [ "),
            "calibration.conf:5: mounting.delta_d",
        ),
        (CONF.replace("0.000391", "x"), "calibration.conf:4: mounting.delta_a"),
        (CONF.replace("[mounting]", "[mount]"), "has no delta_theta"),
    ],
)
def test_bad_calibration_conf_is_named_with_file_line_and_key(text: str, message: str) -> None:
    with pytest.raises(
        FactoryCalibrationError, match=message.replace("[", r"\[").replace(".", r"\.")
    ):
        parse_calibration_conf(text)


def _script_of(model: RobotModel, qs: np.ndarray) -> bytes:
    from calib.programs.rotations import matrix_to_rotvec

    lines = ["def prog():", "  set_tcp(p[0.0,0.0,0.0,0.0,0.0,0.0])"]
    for k, q in enumerate(qs, start=1):
        f = flange_frames(model, q[None])[0]
        p = [*(f[:3, 3] / 1000.0), *matrix_to_rotvec(f[:3, :3])]
        lines.append(f"  global Waypoint_{k}_p=p[{', '.join(f'{v:.12f}' for v in p)}]")
        lines.append(
            f"  global Waypoint_{k}_q=[{', '.join(repr(float(v)) for v in np.deg2rad(q))}]"
        )
    for k in range(1, len(qs) + 1):
        lines.append(f'  $ {k} "Waypoint_{k}"')
        lines.append(
            f"  movej(get_inverse_kin(Waypoint_{k}_p, qnear=Waypoint_{k}_q), a=1.4, v=1.05)"
        )
    return ("\n".join(lines) + "\nend\n").encode()


def test_the_arms_own_model_solves_its_waypoints_to_their_q() -> None:
    """Waypoints written by a controller with its factory table: with that table as the
    filter's nominal, every waypoint is solved to its own q and nothing changes."""
    arm = with_deltas(_ur5e(), parse_calibration_conf(CONF))
    qs = np.array(
        [[-20.0, -80.0, 100.0, -110.0, -90.0, 15.0], [30.0, -120.0, -60.0, 200.0, 70.0, -30.0]]
    )
    data = _script_of(arm, qs)
    run = filter_files(Calibration(arm, arm, None, np.zeros(0, dtype=int)), [("w.script", data)])
    assert run.errors == [] and run.outputs["w.script"] == data
    by = {t.name: c for t, c in zip(run.targets, run.corrections, strict=True)}
    for k, q in enumerate(qs, start=1):
        c = by[f"Waypoint_{k}_p"]
        assert c.status == "corrected" and c.nominal_joints_deg is not None
        np.testing.assert_allclose(c.nominal_joints_deg, q, atol=1e-6)


def test_converter_prints_a_model_file_that_reads_back(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    base = tmp_path / "ur5e.toml"
    base.write_text((LIBRARY / "ur5e.toml").read_text("utf-8"), "utf-8")
    conf = tmp_path / "calibration.conf"
    conf.write_text(CONF, "utf-8")
    assert main([str(base), str(conf), "cell-3-ur5e"]) == 0
    model = model_from_mapping(tomllib.loads(capsys.readouterr().out))
    want = with_deltas(_ur5e(), parse_calibration_conf(CONF))
    assert model.name == "cell-3-ur5e" and model.controller.maker == "ur"
    np.testing.assert_allclose(model.dh_table, want.dh_table, atol=1e-12)
    conf.write_text("[mounting]\n", "utf-8")
    assert main([str(base), str(conf)]) == 2
    assert "has no delta_theta" in capsys.readouterr().err


def _package(kind: int, payload: bytes) -> bytes:
    return struct.pack(">iB", 5 + len(payload), kind) + payload


def _kinematics_message(table: np.ndarray) -> bytes:
    """A robot-state message: joint data, then KinematicsInfo (theta, a, d, alpha)."""
    payload = struct.pack(">6I", 1, 2, 3, 4, 5, 6) + struct.pack(">24d", *table.ravel())
    payload += struct.pack(">I", 2)
    body = _package(1, bytes(41 * 6)) + _package(5, payload)
    return struct.pack(">iB", 5 + len(body), 16) + body


def _factory_table() -> np.ndarray:
    """(4, 6): theta [rad], a [m], d [m], alpha [rad] of the ur5e with the conf's deltas."""
    arm = with_deltas(_ur5e(), parse_calibration_conf(CONF))
    t = arm.dh_table
    return np.array([np.deg2rad(t[:, 3]), t[:, 1] / 1000.0, t[:, 2] / 1000.0, np.deg2rad(t[:, 0])])


@pytest.mark.anyio
async def test_kinematics_info_read_from_the_primary_interface() -> None:
    table = _factory_table()
    version = _package(20, b"\x03" + bytes(20))  # a robot message first (skipped)

    async def serve(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        writer.write(version + _kinematics_message(table))
        await writer.drain()
        await reader.read()
        writer.close()

    server = await asyncio.start_server(serve, "127.0.0.1", 0)
    port = server.sockets[0].getsockname()[1]
    async with server:
        info = await read_kinematics_info("127.0.0.1", port, timeout_s=5.0)
    assert info.checksums == (1, 2, 3, 4, 5, 6) and info.calibration_status == 2
    model = from_kinematics_info(_ur5e(), info.theta_rad, info.a_m, info.d_m, info.alpha_rad)
    want = with_deltas(_ur5e(), parse_calibration_conf(CONF))
    np.testing.assert_allclose(model.dh_table, want.dh_table, atol=1e-9)


@pytest.mark.anyio
async def test_a_stream_that_is_not_the_primary_interface_is_refused() -> None:
    async def serve(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        writer.write(b"HTTP/1.1 200 OK\r\n\r\n")
        await writer.drain()
        await reader.read()
        writer.close()

    server = await asyncio.start_server(serve, "127.0.0.1", 0)
    port = server.sockets[0].getsockname()[1]
    async with server:
        with pytest.raises(PrimaryInterfaceError, match="not a UR primary interface"):
            await read_kinematics_info("127.0.0.1", port, timeout_s=5.0)


def test_a_cut_sub_package_is_named() -> None:
    msg = bytearray(_kinematics_message(_factory_table()))
    struct.pack_into(">i", msg, 5, 10_000)  # the first sub-package claims too much
    with pytest.raises(PrimaryInterfaceError, match="sub-package at byte 5"):
        kinematics_info_in(bytes(msg))
