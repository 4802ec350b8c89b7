"""``cablecal serve --simulated-cell READY.json --robot-kind kuka-varproxy|fanuc-rmi``: the
daemon (a real process) reads the EMULATED KukaVarProxy or RMI face with our driver, and its
sampler auto-captures samples whose joints are the emulated robot's poses."""

from __future__ import annotations

import functools
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest

from daemon.cli.emulated import (
    FAST_DAEMON_ENV,
    DaemonProcess,
    EmulatedCellProcess,
    fast_cell_toml,
    wait_for,
)

#: Samples captured per kind [count].
N_SAMPLES = 2


def _enough_samples(api: httpx.Client, campaign: int) -> list[dict[str, Any]] | None:
    samples: list[dict[str, Any]] = api.get(f"/campaigns/{campaign}/samples").json()
    return samples if len(samples) >= N_SAMPLES else None


@pytest.mark.slow
def test_serve_robot_kind_captures_through_the_kuka_and_fanuc_faces(tmp_path: Path) -> None:
    """One emulated cell, one daemon per kind in turn; each captures N_SAMPLES samples, each
    sample's joints within 0.001 deg of one of the cell's poses (the robot dwells there)."""
    sim_toml = tmp_path / "sim.toml"
    # Enough poses that the (slow, loaded-machine) daemon starts never outlast them.
    sim_toml.write_text(fast_cell_toml(120, seed=3), encoding="utf-8")
    sim = EmulatedCellProcess(sim_toml, tmp_path)
    try:
        poses = np.asarray(sim.control("poses")["poses_deg"])
        for kind, driver in (
            ("kuka-varproxy", "KukaVarProxyRobot"),
            ("fanuc-rmi", "FanucRmiRobot"),
        ):
            state_dir = tmp_path / kind
            state_dir.mkdir()
            daemon = DaemonProcess(
                sim.ready_path,
                state_dir,
                "cell-test-token-emulated",
                env=FAST_DAEMON_ENV,
                extra_args=["--robot-kind", kind],
            )
            try:
                api = daemon.client()
                robot = api.get("/status").json()["devices"]["robot"]
                assert robot["driver"] == driver, robot
                cid = api.post("/campaigns", json={"name": kind, "robot_model": "hsr-jr680"})
                campaign = cid.json()["id"]
                api.put(f"/campaigns/{campaign}/auto-capture", json={"enabled": True})
                samples = wait_for(
                    functools.partial(_enough_samples, api, campaign),
                    timeout_s=60,
                    what=f"{N_SAMPLES} samples through {kind}",
                )
            finally:
                daemon.stop()
            q = np.asarray([[s[f"q{j}"] for j in range(1, 7)] for s in samples])
            nearest_deg = np.abs(poses[None] - q[:, None]).max(axis=2).min(axis=1)
            assert nearest_deg.max() <= 1e-3, (kind, nearest_deg)
    finally:
        sim.stop()
