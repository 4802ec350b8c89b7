"""Plans in the store: saved whole, the newest per campaign, migrated into old files; and the
pose matching behind a plan's progress."""

from __future__ import annotations

import sqlite3
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from _store_helpers import ROBOT

from daemon.store import Store, StoreInvalid, StoreNotFound, apply_migrations


def _pose(i: int, anchor: str = "A") -> dict[str, Any]:
    return {"pose": i, **{f"q{j}": float(10 * i + j) for j in range(1, 7)}, "anchor": anchor}


def test_save_and_latest_plan(store: Store, campaign: dict[str, Any]) -> None:
    cid = campaign["id"]
    with pytest.raises(StoreNotFound, match=f"campaign {cid}: no plan yet"):
        store.latest_plan(cid)
    with pytest.raises(StoreNotFound, match="campaign 999 not found"):
        store.latest_plan(999)
    first = store.save_plan(cid, {"n": 1}, {"condition_number": float("inf")}, [_pose(1)])
    assert first["summary"] == {"condition_number": None}  # strict JSON
    second = store.save_plan(cid, {"n": 2}, {}, [_pose(1), _pose(2)])
    latest = store.latest_plan(cid)
    assert latest == second and latest["id"] > first["id"]
    assert latest["robot_id"] == campaign["robot_id"] and latest["options"] == {"n": 2}
    with pytest.raises(StoreInvalid, match="poses: a plan needs"):
        store.save_plan(cid, {}, {}, [])
    with pytest.raises(StoreInvalid, match=r"poses\[0\]: missing q6, anchor"):
        store.save_plan(cid, {}, {}, [{"q1": 0, "q2": 0, "q3": 0, "q4": 0, "q5": 0}])
    with pytest.raises(StoreNotFound):
        store.save_plan(999, {}, {}, [_pose(1)])


def test_an_older_file_gets_the_plans_table(tmp_path: Path) -> None:
    path = tmp_path / "old.sqlite3"
    conn = sqlite3.connect(path)
    apply_migrations(conn, upto=2)
    conn.close()
    with Store(path) as s:
        cid = s.create_campaign("c", s.ensure_builtin_robot(ROBOT)["id"])["id"]
        assert s.save_plan(cid, {}, {}, [_pose(1)])["poses"] == [_pose(1)]


def test_a_result_off_the_plan_says_so_and_what_it_cost(
    store: Store, campaign: dict[str, Any]
) -> None:
    """The issue's case: 40 planned poses, 31 samples at poses of the robot's own, TCP σ 0.84
    mm against 0.063 planned: the result says 0 of 40 measured and the x13 cost."""
    from calib.dataset import make_samples
    from daemon.jobs.plan_check import add_plan_check

    cid = campaign["id"]
    base = np.array([0.0, -30.0, 150.0, 0.0, 20.0, 0.0])
    step = np.array([2.0, 1.0, 1.0, 1.0, 0.5, -1.0])
    plan_q = np.array([base + i * step for i in range(1, 41)])
    poses = [
        {"pose": i + 1, **{f"q{j + 1}": float(v) for j, v in enumerate(q)}, "anchor": "A"}
        for i, q in enumerate(plan_q)
    ]
    summary = {"tcp_sigma_mm": {"plan": {"rms": 0.063, "max": 0.1}}, "noise_mm": 0.05}
    store.save_plan(cid, {}, summary, poses)
    own = plan_q[:31] + 3.0  # the robot's own poses, 3 deg off the plan
    ids = store.import_samples(cid, make_samples(own, np.full(31, 900.0), ["A"] * 31))
    result: dict[str, Any] = {"tcp_uncertainty_mm": {"rms": 0.84, "max": 1.2}, "notes": []}
    result = add_plan_check(store, cid, ids, result)
    check = result["plan_check"]
    assert (check["n_planned"], check["n_measured"], check["n_off_plan"]) == (40, 0, 31)
    assert not check["on_plan"] and check["sigma_ratio"] == pytest.approx(0.84 / 0.063)
    assert "0 of 40 planned poses measured, 31 samples off the plan" in result["notes"][0]
    assert "0.840 mm against 0.063 mm planned (x13.33)" in result["notes"][0]
    # On the plan (within the tolerance): no note, the check says so.
    on = plan_q + 0.01
    ids = store.import_samples(cid, make_samples(on, np.full(40, 900.0), ["A"] * 40))
    result = {"tcp_uncertainty_mm": {"rms": 0.07, "max": 0.1}, "notes": []}
    result = add_plan_check(store, cid, ids, result)
    assert result["plan_check"]["on_plan"] and result["plan_check"]["n_off_plan"] == 0
    assert result["notes"] == []
