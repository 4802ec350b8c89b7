"""Robots, campaigns and captured samples in the store."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from _store_helpers import ROBOT, make_capture, sample_count
from sqlite_utils.db import Table

from calib.models import builtin_model
from daemon.store import Store, StoreInvalid, StoreNotFound
from daemon.store.campaigns import _CAMPAIGN_SELECT


# ----------------------------------------------------------------------------- robots
def test_builtin_robot_is_created_once_and_round_trips(store: Store) -> None:
    first = store.ensure_builtin_robot(ROBOT)
    again = store.ensure_builtin_robot(ROBOT)
    assert again["id"] == first["id"]
    assert first["source"] == "builtin" and first["name"] == ROBOT
    assert first["model"] == builtin_model(ROBOT).to_dict()
    model = store.robot_model(first["id"])
    np.testing.assert_array_equal(model.dh_table, builtin_model(ROBOT).dh_table)
    assert model.joint_limits_deg is not None
    uploaded = store.add_robot(builtin_model(ROBOT), name="cell 2")
    assert uploaded["source"] == "uploaded" and uploaded["id"] != first["id"]
    assert [r["id"] for r in store.list_robots()] == [first["id"], uploaded["id"]]
    assert store.get_robot(999) is None
    with pytest.raises(StoreNotFound, match="robot 999 not found") as err:
        store.robot_model(999)
    assert isinstance(err.value, KeyError) and err.value.kind == "robot"


# -------------------------------------------------------------------------- campaigns
def test_campaigns_with_counts_and_auto_capture(store: Store, campaign: dict[str, Any]) -> None:
    assert campaign["name"] == "cell 1" and campaign["robot_name"] == ROBOT
    assert campaign["auto_capture"] is False and campaign["n_samples"] == 0
    cid = campaign["id"]
    ids = [
        store.store_capture(cid, make_capture((0, 0, 90, 0, 0, k), 500.0))["id"] for k in range(3)
    ]
    store.set_excluded(ids[0], True, "outlier")
    other = store.create_campaign("cell 2", campaign["robot_id"])
    listed = {c["id"]: c for c in store.list_campaigns()}
    assert (listed[cid]["n_samples"], listed[cid]["n_included"], listed[cid]["n_excluded"]) == (
        3,
        2,
        1,
    )
    assert listed[other["id"]]["n_samples"] == 0

    on = store.set_auto_capture(cid, True, anchor="B")
    assert on["auto_capture"] is True and on["auto_anchor"] == "B"
    assert [c["id"] for c in store.auto_capture_campaigns()] == [cid]
    store.set_auto_capture(cid, False)
    assert store.auto_capture_campaigns() == []

    assert store.find_campaign(str(cid))["id"] == cid
    assert store.find_campaign("cell 2")["id"] == other["id"]
    store.create_campaign("cell 2", campaign["robot_id"])
    with pytest.raises(StoreInvalid, match="2 campaigns are named 'cell 2'"):
        store.find_campaign("cell 2")
    with pytest.raises(StoreNotFound, match="campaign 'nope' not found"):
        store.find_campaign("nope")
    with pytest.raises(StoreNotFound, match="robot 42"):
        store.create_campaign("x", 42)
    with pytest.raises(StoreNotFound, match="campaign 42"):
        store.set_auto_capture(42, True)
    with pytest.raises(StoreInvalid, match="name"):
        store.create_campaign("  ", campaign["robot_id"])
    assert store.get_campaign(42) is None


def test_campaign_anchors_are_those_of_the_included_samples(
    store: Store, campaign: dict[str, Any]
) -> None:
    cid = campaign["id"]
    assert store.campaign(cid)["anchors"] == []
    ids = {
        a: store.store_capture(cid, make_capture((0, 0, 90, 0, 0, k), 500.0, anchor=a))["id"]
        for k, a in enumerate(("C", "A", "B,x"))
    }
    store.store_capture(cid, make_capture((0, 0, 90, 0, 0, 9), 500.0, anchor="A"))
    assert store.campaign(cid)["anchors"] == ["A", "B,x", "C"]  # sorted, each once
    store.set_excluded(ids["C"], True, "moved the sensor")
    assert [c["anchors"] for c in store.list_campaigns()] == [["A", "B,x"]]
    # The counts and the anchors come from indexes (the anchors by a skip scan), never from a
    # read of the sample rows.
    sql = "EXPLAIN QUERY PLAN " + _CAMPAIGN_SELECT + " WHERE c.id = ?"
    plan = [str(row[-1]) for row in store.conn.execute(sql, (cid,)).fetchall()]
    on_samples = [p for p in plan if p.startswith(("SEARCH s ", "SCAN s"))]
    assert len(on_samples) == 4, plan  # n_samples, n_excluded, the first and the next anchor
    assert all("COVERING INDEX" in p for p in on_samples), plan
    assert sum("samples_campaign_anchor" in p for p in on_samples) == 3, plan


# ---------------------------------------------------------------------------- samples
def test_capture_round_trip_with_raw_readings(tmp_path: Path) -> None:
    path = tmp_path / "db.sqlite3"
    with Store(path) as s:
        cid = s.create_campaign("c", s.ensure_builtin_robot(ROBOT)["id"])["id"]
        cap = make_capture((10.5, -20.25, 95.125, 1, 2, 3), 812.34567, n_raw=5, mode="auto")
        row = s.store_capture(cid, cap)
    with Store(path) as s:  # committed: visible after reopening
        got = s.get_sample(row["id"])
        assert got == row
        assert [got[f"q{j + 1}"] for j in range(6)] == list(cap.joints_deg)
        assert got["length_mm"] == cap.length_mm and got["length_std_mm"] == cap.length_std_mm
        assert [got[f"q{j + 1}_std"] for j in range(6)] == list(cap.joints_std_deg)
        assert (got["count"], got["mode"], got["source"]) == (5, "auto", "capture")
        assert got["anchor"] == "A"
        assert (got["t_start"], got["t_end"]) == (cap.t_start_wall, cap.t_end_wall)
        assert got["excluded"] is False and got["excluded_reason"] is None
        raw = s.raw_readings(row["id"])
        assert [r["t_wall"] for r in raw] == [r.t_wall for r in cap.raw]
        assert [r["length_mm"] for r in raw] == [r.length_mm for r in cap.raw]
        np.testing.assert_array_equal(s.poses_deg(cid), [cap.joints_deg])
        assert s.get_sample(999) is None


def test_capture_for_missing_campaign_is_not_found_and_stores_nothing(store: Store) -> None:
    with pytest.raises(StoreNotFound, match="campaign 7 not found"):
        store.store_capture(7, make_capture((0, 0, 90, 0, 0, 0), 500.0))
    assert sample_count(store.path) == 0


@pytest.mark.parametrize(
    ("change", "pattern"),
    [
        ({"length_mm": math.nan}, "length_mm"),
        ({"joints_deg": (0.0, math.inf, 90.0, 0.0, 0.0, 0.0)}, r"joints_deg\[1\]"),
        ({"count": 0}, "count"),
        ({"anchor": " "}, "anchor"),
    ],
)
def test_capture_with_bad_values_is_refused(
    store: Store, campaign: dict[str, Any], change: dict[str, Any], pattern: str
) -> None:
    import dataclasses

    cap = dataclasses.replace(make_capture((0, 0, 90, 0, 0, 0), 500.0), **change)
    with pytest.raises(StoreInvalid, match=pattern):
        store.store_capture(campaign["id"], cap)
    assert sample_count(store.path) == 0


def test_capture_is_one_transaction(
    store: Store, campaign: dict[str, Any], monkeypatch: pytest.MonkeyPatch
) -> None:
    """The raw readings fail after the sample row was written: neither is kept."""
    real = Table.insert_all

    def insert_then_fail(self: Table, *args: Any, **kwargs: Any) -> Table:
        real(self, *args, **kwargs)
        raise RuntimeError("disk on fire")

    monkeypatch.setattr(Table, "insert_all", insert_then_fail)
    with pytest.raises(RuntimeError, match="disk on fire"):
        store.store_capture(campaign["id"], make_capture((0, 0, 90, 0, 0, 0), 500.0))
    monkeypatch.undo()
    assert sample_count(store.path) == 0
    assert store.list_samples(campaign["id"]) == []
    store.store_capture(campaign["id"], make_capture((0, 0, 90, 0, 0, 0), 500.0))  # usable
    assert sample_count(store.path) == 1


def test_exclude_and_include(store: Store, campaign: dict[str, Any]) -> None:
    sid = store.store_capture(campaign["id"], make_capture((0, 0, 90, 0, 0, 0), 500.0))["id"]
    row = store.set_excluded(sid, True, "cable slipped")
    assert row["excluded"] is True and row["excluded_reason"] == "cable slipped"
    assert store.list_samples(campaign["id"], include_excluded=False) == []
    assert len(store.list_samples(campaign["id"])) == 1
    row = store.set_excluded(sid, False, "ignored when including")
    assert row["excluded"] is False and row["excluded_reason"] is None
    with pytest.raises(StoreNotFound, match="sample 999 not found"):
        store.set_excluded(999, True, "x")
    with pytest.raises(StoreNotFound, match="campaign 5"):
        store.list_samples(5)


def test_sample_set_carries_capture_times_and_an_import_the_row_order(
    store: Store, campaign: dict[str, Any]
) -> None:
    """Captured samples give the drift model their capture times (calib.drift); imported ones
    have none, and the row order stands in."""
    cid = campaign["id"]
    for k in range(3):
        q = [float(k), -20.0, 180.0, 0.0, 30.0, float(k)]
        store.store_capture(cid, make_capture(q, 500.0 + k, t0=1000.0 + 20.0 * k))
    samples, _ = store.sample_set(cid)
    assert samples.t_s is not None
    assert samples.t_s.tolist() == pytest.approx([0.0, 20.0, 40.0], abs=1.0)
    other = store.create_campaign("cell 2", campaign["robot_id"])
    store.import_samples(other["id"], samples)
    assert store.sample_set(other["id"])[0].t_s is None
