"""``cablecal serve --simulated-cell cell.json --robot-kind KIND`` captures through each
controller face of the emulated cell (issue 18), with real processes on loopback."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from daemon.cli.emulated import (
    FAST_DAEMON_ENV,
    DaemonProcess,
    EmulatedCellProcess,
    fast_cell_toml,
)

pytestmark = [pytest.mark.slow, pytest.mark.timeout(180)]

#: Each controller kind of issue 18 and the driver class the daemon must pick for it.
DRIVERS = {
    "ur-rtde": "UrRtdeRobot",
    "abb-rws": "AbbRwsRobot",
    "kuka-varproxy": "KukaVarProxyRobot",
    "fanuc-rmi": "FanucRmiRobot",
}


@pytest.fixture(scope="module")
def cell(tmp_path_factory: pytest.TempPathFactory) -> EmulatedCellProcess:
    workdir = tmp_path_factory.mktemp("cell")
    path = workdir / "sim.toml"
    path.write_text(fast_cell_toml(n_poses=4, seed=5), encoding="utf-8")
    sim = EmulatedCellProcess(path, workdir)
    sim.control("hold", on=True)
    yield sim  # type: ignore[misc]
    sim.stop()


@pytest.mark.parametrize("kind", DRIVERS)
def test_serve_captures_through_the_face_of_each_kind(
    cell: EmulatedCellProcess, tmp_path: Path, kind: str
) -> None:
    daemon = DaemonProcess(
        cell.ready_path,
        tmp_path,
        "controllers-test-token",
        env=FAST_DAEMON_ENV,
        extra_args=["--robot-kind", kind],
    )
    try:
        api = daemon.client()
        status = api.get("/status").json()
        robot = next(d for d in status["devices"].values() if d.get("role") == "robot")
        assert robot["driver"] == DRIVERS[kind]
        cid = api.post("/campaigns", json={"name": kind, "robot_model": "hsr-jr680"}).json()["id"]
        r = api.post(f"/campaigns/{cid}/captures", json={})
        assert r.status_code == 201, r.text
        sample = r.json()
        truth = np.asarray(cell.control("state")["joints_deg"])
        q = np.array([sample[f"q{j}"] for j in range(1, 7)])
        assert np.abs(q - truth).max() <= 0.01, (q, truth)
    finally:
        daemon.stop()
    log = (tmp_path / "daemon.log").read_text(encoding="utf-8")
    assert "robotics" not in log  # the emulated controller's password is never logged
