"""The robot-kind registry, the face registry, ``--robot-kind`` and controller credentials
(issue 18: the plumbing every controller family plugs into)."""

from __future__ import annotations

import os
import socket
from pathlib import Path

import pytest
from pydantic import SecretStr

from daemon.config import ConfigError, Settings, ready_key, simulated_cell_overrides
from drivers import ROBOT_KINDS, ManualRobot, make_robot
from drivers.credentials import CredentialsError, read_secret, write_secret
from simulator.faces import FACE_READY_KEYS, FACES
from simulator.faces.base import free_loopback_host
from simulator.runner import READY_KEYS


def test_make_robot_dispatches_through_the_table(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("CABLECAL_ROBOT_PASSWORD", "for-the-kinds-with-a-login")
    for kind, entry in ROBOT_KINDS.items():
        config = entry.config.model_validate({"kind": kind})
        assert make_robot({"kind": kind}).__class__ is entry.driver
        assert make_robot(config).__class__ is entry.driver
        # The daemon's [robot] settings accept every kind of the table.
        assert type(Settings(robot={"kind": kind}).robot) is entry.config
    assert isinstance(make_robot({"kind": "manual"}), ManualRobot)
    with pytest.raises(ValueError, match="unknown robot driver 'kuka'; use manual, huashu"):
        make_robot({"kind": "kuka"})


def test_every_face_has_a_ready_key_a_config_table_and_a_driver() -> None:
    assert set(FACE_READY_KEYS) <= set(READY_KEYS)
    for kind, face in FACES.items():
        assert face.ready_key == face.table == ready_key(kind)
        assert kind in ROBOT_KINDS  # a face the daemon cannot read would be a toy


READY = {
    "indicator_port": "/tmp/x/indicator",
    "robot_socketcmd": "127.0.0.1:2001",
    "robot_modbus": "127.0.0.1:2002",
    "robot_ur_rtde": "127.0.0.7:30004",
    "robot_abb_rws": None,
}


def test_simulated_cell_overrides_pick_the_face_of_the_kind() -> None:
    settings = Settings()
    assert simulated_cell_overrides(READY, settings)["robot"]["kind"] == "huashu-socketcmd"
    robot = simulated_cell_overrides(READY, settings, "modbus-tcp")["robot"]
    assert (robot["host"], robot["port"], robot["preset"]) == ("127.0.0.1", 2002, "ur")
    if "ur-rtde" in ROBOT_KINDS:
        robot = simulated_cell_overrides(READY, settings, "ur-rtde")["robot"]
        assert (robot["kind"], robot["host"], robot["port"]) == ("ur-rtde", "127.0.0.7", 30004)
    with pytest.raises(ConfigError, match="unknown kind 'manual'"):
        simulated_cell_overrides(READY, settings, "manual")
    if "abb-rws" in ROBOT_KINDS:
        with pytest.raises(ConfigError, match="no robot_abb_rws endpoint"):
            simulated_cell_overrides(READY, settings, "abb-rws")


def test_secret_from_env_or_a_0600_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("CABLECAL_TEST_SECRET", "s3cret-value")
    secret = read_secret("CABLECAL_TEST_SECRET", None, "password")
    assert secret.get_secret_value() == "s3cret-value"
    assert "s3cret" not in repr(secret) and "s3cret" not in str(secret)
    path = write_secret(tmp_path / "pw", "from-file")
    assert os.stat(path).st_mode & 0o777 == 0o600
    assert read_secret("CABLECAL_TEST_SECRET", path, "password") == SecretStr("from-file")
    path.chmod(0o644)
    with pytest.raises(CredentialsError, match=r"password_file: .* has mode 0644.*chmod 600"):
        read_secret(None, path, "password")
    monkeypatch.delenv("CABLECAL_TEST_SECRET")
    with pytest.raises(CredentialsError, match="CABLECAL_TEST_SECRET is unset"):
        read_secret("CABLECAL_TEST_SECRET", None, "password")
    with pytest.raises(CredentialsError, match="password_file: cannot read"):
        read_secret(None, tmp_path / "missing", "password")


def test_auto_host_skips_a_taken_loopback_address() -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        assert free_loopback_host(port, ("127.0.0.1", "127.0.0.3")) == "127.0.0.3"
    with pytest.raises(ValueError, match="not a loopback"):
        free_loopback_host(port, ("10.0.0.1",))


def test_serve_refuses_a_password_file_others_can_read(tmp_path: Path) -> None:
    """``cablecal serve`` checks the controller password's source before anything starts;
    the error names the setting, the file and the fix, never the password."""
    from daemon.cli.serve import load_settings

    secret = write_secret(tmp_path / "rws-password", "hunter2-not-shown")
    secret.chmod(0o644)
    config = tmp_path / "cablecal.toml"
    config.write_text(f'[robot]\nkind = "abb-rws"\npassword_file = "{secret}"\n', encoding="utf-8")
    with pytest.raises(ConfigError, match=r"robot\.password_file: .* mode 0644") as info:
        load_settings(config, None, None, None)
    assert "hunter2" not in str(info.value)
    secret.chmod(0o600)
    assert load_settings(config, None, None, None).robot.model_dump()["kind"] == "abb-rws"
