"""The SQLite store (daemon/store.py) and ``cablecal db export``, on real temporary files."""

from __future__ import annotations

import json
import math
import os
import signal
import sqlite3
import subprocess
import sys
import textwrap
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import typer
from sqlite_utils.db import Table
from typer.testing import CliRunner

from calib.dataset import SampleError, make_samples, parse_samples_csv
from calib.models import builtin_model
from daemon.capture import Capture, RawReading
from daemon.cli import db as cli_db
from daemon.store import (
    INTERRUPTED_ERROR,
    SCHEMA_VERSION,
    Store,
    StoreError,
    StoreInvalid,
    StoreNotFound,
    apply_migrations,
)

ROBOT = "hsr-jr680"
#: Inside the built-in model's joint limits [deg], with a margin.
JOINT_RANGE_DEG = np.array(
    [[-170, 170], [-150, 80], [70, 290], [-350, 350], [-120, 120], [-350, 350]], dtype=float
)
REPO = Path(__file__).resolve().parents[1]


def make_capture(
    joints_deg: tuple[float, ...] | np.ndarray,
    length_mm: float,
    *,
    n_raw: int = 3,
    anchor: str = "A",
    mode: str = "manual",
    t0: float = 1_700_000_000.0,
) -> Capture:
    """A capture whose mean is ``joints_deg``/``length_mm``, with ``n_raw`` raw readings."""
    q = tuple(float(v) for v in joints_deg)
    raw = tuple(
        RawReading(t0 + 0.1 * k, q, length_mm + 0.001 * (k - (n_raw - 1) / 2))  # type: ignore[arg-type]
        for k in range(n_raw)
    )
    return Capture(
        joints_deg=q,  # type: ignore[arg-type]
        joints_std_deg=(0.001,) * 6,
        length_mm=float(length_mm),
        length_std_mm=0.0008,
        count=max(n_raw, 1),
        anchor=anchor,
        t_start_wall=t0,
        t_end_wall=t0 + 0.1 * max(n_raw - 1, 0),
        mode=mode,  # type: ignore[arg-type]
        raw=raw,
    )


def random_joints(rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 6) joint angles [deg] inside :data:`JOINT_RANGE_DEG`."""
    lo, hi = JOINT_RANGE_DEG[:, 0], JOINT_RANGE_DEG[:, 1]
    return np.asarray(lo + rng.random((n, 6)) * (hi - lo))


def csv_text(n: int, seed: int = 0, *, groups: bool = False) -> str:
    """A valid samples CSV with ``n`` rows (3 decimals), anchors A/B, optional groups."""
    rng = np.random.default_rng(seed)
    q = random_joints(rng, n)
    length = 300.0 + rng.random(n) * 1500.0
    lines = ["q1,q2,q3,q4,q5,q6,L,anchor" + (",group" if groups else "")]
    for i in range(n):
        cells = [f"{v:.3f}" for v in q[i]] + [f"{length[i]:.3f}", "AB"[i % 2]]
        if groups:
            cells.append(f"g{i // 4}")
        lines.append(",".join(cells))
    return "\n".join(lines) + "\n"


def replace_cell(text: str, line_no: int, column: int, value: str) -> str:
    """``text`` with the cell at file line ``line_no`` (header = 1), column index replaced."""
    lines = text.splitlines()
    cells = lines[line_no - 1].split(",")
    cells[column] = value
    lines[line_no - 1] = ",".join(cells)
    return "\n".join(lines) + "\n"


@pytest.fixture
def store(tmp_path: Path) -> Iterator[Store]:
    s = Store(tmp_path / "state" / "cablecal.sqlite3")
    yield s
    s.close()


@pytest.fixture
def campaign(store: Store) -> dict[str, Any]:
    robot = store.ensure_builtin_robot(ROBOT)
    return store.create_campaign("cell 1", robot["id"], notes="test")


def sample_count(path: Path) -> int:
    """Rows in ``samples``, through an independent connection."""
    with sqlite3.connect(path) as conn:
        return int(conn.execute("SELECT count(*) FROM samples").fetchone()[0])


# ---------------------------------------------------------------------------- opening
def test_open_creates_file_in_wal_mode_with_full_sync(tmp_path: Path) -> None:
    path = Store.default_path(tmp_path / "new" / "dir")
    assert path == tmp_path / "new" / "dir" / "cablecal.sqlite3"
    with Store(path) as s:
        assert path.is_file()
        assert s.pragma("journal_mode") == "wal"
        assert s.pragma("synchronous") == 2  # FULL
        assert s.pragma("foreign_keys") == 1
        assert s.pragma("busy_timeout") >= 1000
        assert s.schema_version == SCHEMA_VERSION
        assert s.integrity_check() == "ok"
    with sqlite3.connect(path) as conn:  # WAL is persistent in the file
        assert conn.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
        tables = {r[0] for r in conn.execute("SELECT name FROM sqlite_master WHERE type='table'")}
        indexes = {r[0] for r in conn.execute("SELECT name FROM sqlite_master WHERE type='index'")}
    assert {"robots", "campaigns", "samples", "raw_readings", "jobs", "results", "events",
            "schema_version"} <= tables  # fmt: skip
    assert {"samples_campaign_id", "raw_readings_sample_id", "events_kind",
            "jobs_campaign_id", "results_robot_id"} <= indexes  # fmt: skip


def test_closed_store_raises_store_error(tmp_path: Path) -> None:
    s = Store(tmp_path / "db.sqlite3")
    s.close()
    s.close()  # idempotent
    with pytest.raises(StoreError, match="closed"):
        s.list_campaigns()


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
    uploaded = store.add_robot(builtin_model(ROBOT))
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
    ids = [store.store_capture(cid, make_capture((0, 0, 90, 0, 0, k), 500.0))["id"]
           for k in range(3)]  # fmt: skip
    store.set_excluded(ids[0], True, "outlier")
    other = store.create_campaign("cell 2", campaign["robot_id"])
    listed = {c["id"]: c for c in store.list_campaigns()}
    assert (listed[cid]["n_samples"], listed[cid]["n_included"], listed[cid]["n_excluded"]) == (
        3, 2, 1,
    )  # fmt: skip
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


@pytest.mark.parametrize(
    ("column_index", "value", "column", "pattern"),
    [(3, "abc", "q4", "not a number"), (6, "2500", "L", "outside the sensor range")],
)
def test_import_csv_with_bad_row_37_stores_nothing(
    store: Store,
    campaign: dict[str, Any],
    column_index: int,
    value: str,
    column: str,
    pattern: str,
) -> None:
    text = replace_cell(csv_text(60), 37, column_index, value)
    with pytest.raises(SampleError, match=pattern) as err:
        store.import_csv(campaign["id"], text)
    assert (err.value.row, err.value.column) == (37, column)
    assert f"row 37, column '{column}'" in str(err.value)
    assert sample_count(store.path) == 0


def test_import_joint_limit_violation_names_row_and_column(
    store: Store, campaign: dict[str, Any]
) -> None:
    text = replace_cell(csv_text(20), 12, 2, "10.0")  # q3 limits of hsr-jr680: [60, 300]
    with pytest.raises(SampleError, match="outside the limits") as err:
        store.import_csv(campaign["id"], text)
    assert (err.value.row, err.value.column) == (12, "q3")
    assert sample_count(store.path) == 0


def test_import_samples_is_all_or_nothing(
    store: Store, campaign: dict[str, Any], monkeypatch: pytest.MonkeyPatch
) -> None:
    samples = parse_samples_csv(csv_text(50))
    real = Table.insert_all

    def insert_then_fail(self: Table, *args: Any, **kwargs: Any) -> Table:
        real(self, *args, **kwargs)
        raise sqlite3.OperationalError("database or disk is full")

    monkeypatch.setattr(Table, "insert_all", insert_then_fail)
    with pytest.raises(sqlite3.OperationalError):
        store.import_samples(campaign["id"], samples)
    monkeypatch.undo()
    assert sample_count(store.path) == 0
    ids = store.import_samples(campaign["id"], samples)
    assert len(ids) == 50 and ids == sorted(ids)
    with pytest.raises(StoreNotFound, match="campaign 99"):
        store.import_csv(99, "not even csv")


def test_import_of_a_sample_set_checks_values(store: Store, campaign: dict[str, Any]) -> None:
    samples = make_samples(np.array([[0, 0, 90, 0, 0, 0], [0, 0, 400, 0, 0, 0]], float),
                           np.array([500.0, 600.0]))  # fmt: skip
    with pytest.raises(SampleError) as err:
        store.import_samples(campaign["id"], samples)
    assert (err.value.row, err.value.column) == (3, "q3")
    assert sample_count(store.path) == 0


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


def test_export_csv_round_trips_through_parse_samples_csv(
    store: Store, campaign: dict[str, Any]
) -> None:
    cid = campaign["id"]
    text = csv_text(30, seed=3, groups=True)
    imported = parse_samples_csv(text)
    ids = store.import_csv(cid, text)
    rng = np.random.default_rng(4)
    captured = random_joints(rng, 3)
    cap_rows = [store.store_capture(cid, make_capture(q, 700.0 + np.pi * k, anchor="B"))
                for k, q in enumerate(captured)]  # fmt: skip
    store.set_excluded(ids[5], True, "outlier")

    samples, sample_ids = store.sample_set(cid)
    assert sample_ids == [i for i in ids if i != ids[5]] + [r["id"] for r in cap_rows]
    again = parse_samples_csv(store.export_csv(cid))
    assert len(again) == len(samples) == 32
    keep = [i for i in range(30) if i != 5]
    # Imported values have 3 decimals: the 6-decimal CSV reproduces them exactly.
    np.testing.assert_array_equal(again.joints_deg[:29], imported.joints_deg[keep])
    np.testing.assert_array_equal(again.length_mm[:29], imported.length_mm[keep])
    # Captured means carry full precision: equal to the CSV's 6 decimals.
    np.testing.assert_allclose(again.joints_deg[29:], captured, rtol=0, atol=5e-7)
    np.testing.assert_allclose(again.length_mm[29:], 700.0 + np.pi * np.arange(3), atol=5e-7)
    np.testing.assert_allclose(again.joints_deg, samples.joints_deg, rtol=0, atol=5e-7)
    assert again.anchor == samples.anchor == tuple(imported.anchor[i] for i in keep) + ("B",) * 3
    assert imported.group is not None and again.group is not None
    assert again.group == tuple(imported.group[i] for i in keep) + ("",) * 3
    assert samples.line_of(0) == 2


def test_export_csv_of_an_empty_campaign_is_the_header(
    store: Store, campaign: dict[str, Any]
) -> None:
    assert store.export_csv(campaign["id"]) == "q1,q2,q3,q4,q5,q6,L,anchor\n"
    assert store.poses_deg(campaign["id"]).shape == (0, 6)
    with pytest.raises(StoreNotFound):
        store.export_csv(99)


def test_export_json_has_campaign_robot_and_flagged_samples(
    store: Store, campaign: dict[str, Any]
) -> None:
    cid = campaign["id"]
    a = store.store_capture(cid, make_capture((0, 0, 90, 0, 0, 0), 500.0))
    store.import_csv(cid, csv_text(2))
    store.set_excluded(a["id"], True, "moved")
    data = store.export_json(cid, include_raw=True)
    json.dumps(data, allow_nan=False)  # strict JSON
    assert data["format"] == "cablecal-campaign" and data["schema_version"] == SCHEMA_VERSION
    assert data["campaign"]["id"] == cid and data["robot"]["name"] == ROBOT
    assert data["robot"]["model"]["joints"][0]["a_mm"] == 250.0
    first, second = data["samples"][0], data["samples"][1]
    assert first["excluded"] is True and first["excluded_reason"] == "moved"
    assert first["count"] == 3 and first["q1_std"] == 0.001 and len(first["raw_readings"]) == 3
    assert second["source"] == "import" and second["count"] is None and second["q1_std"] is None
    assert "raw_readings" not in store.export_json(cid)["samples"][0]


# ----------------------------------------------------------------------- jobs/results
def test_jobs_lifecycle_and_mark_interrupted(tmp_path: Path) -> None:
    path = tmp_path / "db.sqlite3"
    with Store(path) as s:
        rid = s.ensure_builtin_robot(ROBOT)["id"]
        cid = s.create_campaign("c", rid)["id"]
        queued = s.create_job(cid, rid, "ukf-vslm", {"seed": 1, "fix": ["a1"]})
        assert queued["status"] == "queued" and queued["progress"] == 0.0
        assert queued["interrupted"] is False
        assert queued["options"] == {"seed": 1, "fix": ["a1"]}
        running = s.update_job(s.create_job(cid, rid, "lm", {})["id"], status="running",
                               progress=0.4, message="epoch 1")  # fmt: skip
        assert running["started_at"] is not None and running["progress"] == 0.4
        done = s.create_job(cid, rid, "lm", {})["id"]
        s.update_job(done, status="running")
        finished = s.update_job(done, status="succeeded", progress=1.0)
        assert finished["finished_at"] >= finished["started_at"]
        with pytest.raises(StoreInvalid, match="progress"):
            s.update_job(done, progress=1.5)
        with pytest.raises(StoreInvalid, match="status"):
            s.update_job(done, status="exploded")
        with pytest.raises(StoreInvalid, match="colour: unknown job field"):
            s.update_job(done, colour="red")
        with pytest.raises(StoreNotFound, match="job 99 not found"):
            s.update_job(99, status="failed")
        with pytest.raises(StoreNotFound, match="campaign 99"):
            s.create_job(99, rid, "lm", {})
        assert [j["id"] for j in s.list_jobs(cid)] == [queued["id"], running["id"], done]
        assert s.list_jobs(cid + 1) == [] and len(s.list_jobs()) == 3
    with Store(path) as s:  # the daemon restarts
        assert s.mark_interrupted() == 2
        for job_id in (queued["id"], running["id"]):
            job = s.get_job(job_id)
            assert job is not None
            assert job["status"] == "failed" and job["interrupted"] is True
            assert job["error"] == INTERRUPTED_ERROR
            assert job["finished_at"] is not None
        untouched = s.get_job(done)
        assert untouched is not None
        assert untouched["status"] == "succeeded" and untouched["interrupted"] is False
        assert s.mark_interrupted() == 0
        assert s.get_job(99) is None


def fake_result(offset_mm: float) -> dict[str, Any]:
    """The parts of :meth:`IdentifyResult.to_json` the store reads, plus a NaN metric
    (what ``to_json`` gives for the test figures of a run with ``test_fraction=0``)."""
    dh = [{"joint": j + 1, "alpha_deg": 0.0, "a_mm": 100.0 + offset_mm, "d_mm": 0.0,
           "theta_deg": 0.0} for j in range(6)]  # fmt: skip
    figures = {"rmse_mm": 0.1 + offset_mm, "mae_mm": 0.08, "std_mm": 0.1, "max_mm": 0.3}
    return {
        "robot": ROBOT, "method": "ukf-vslm", "convention": "dh", "dh": dh,
        "tool_mm": [0.0, 0.0, 50.0 + offset_mm],
        "metrics": {"before": {"train": figures, "test": {**figures, "rmse_mm": math.nan}},
                    "after": {"train": figures, "test": figures}},
    }  # fmt: skip


def test_results_and_latest_calibrated_model(store: Store, campaign: dict[str, Any]) -> None:
    rid, cid = campaign["robot_id"], campaign["id"]
    assert store.latest_calibrated_model(rid) is None
    with pytest.raises(StoreNotFound, match="robot 77"):
        store.latest_calibrated_model(77)
    jobs = [store.create_job(cid, rid, "ukf-vslm", {})["id"] for _ in range(3)]
    first = store.save_result(jobs[0], fake_result(1.0))
    assert first["accepted"] is True and first["campaign_id"] == cid
    assert first["result"]["dh"][0]["a_mm"] == 101.0
    assert first["result"]["metrics"]["before"]["test"]["rmse_mm"] is None  # strict JSON
    json.dumps(first, allow_nan=False)
    second = store.save_result(jobs[1], fake_result(2.0))
    store.save_result(jobs[2], fake_result(3.0), accepted=False)
    with pytest.raises(StoreError, match="already has a result"):
        store.save_result(jobs[0], fake_result(9.0))
    with pytest.raises(StoreNotFound, match="job 99"):
        store.save_result(99, {})

    latest = store.latest_calibrated_model(rid)
    assert latest is not None
    assert (latest["job_id"], latest["result_id"], latest["campaign_id"]) == (
        jobs[1], second["id"], cid,
    )  # fmt: skip
    assert latest["robot"] == ROBOT and latest["convention"] == "dh"
    assert latest["dh"][0]["a_mm"] == 102.0 and latest["tool_mm"] == [0.0, 0.0, 52.0]
    assert latest["metrics"]["test"]["rmse_mm"] == pytest.approx(2.1)
    store.set_result_accepted(second["id"], False)
    latest = store.latest_calibrated_model(rid)
    assert latest is not None and latest["job_id"] == jobs[0]
    got = store.get_result_for_job(jobs[2])
    assert got is not None and got["accepted"] is False
    assert store.get_result_for_job(12345) is None


def test_a_real_identify_result_is_stored_as_strict_json(
    store: Store, campaign: dict[str, Any]
) -> None:
    """``IdentifyResult.to_json`` of a run without test rows has NaN test metrics."""
    from calib.identify import IdentifyOptions, identify
    from daemon.datafiles import bundled_dataset_text

    rid, cid = campaign["robot_id"], campaign["id"]
    store.import_samples(cid, parse_samples_csv(bundled_dataset_text()).subset(np.arange(60)))
    samples, _ = store.sample_set(cid)
    result = identify(
        store.robot_model(rid), samples, IdentifyOptions(method="lm", test_fraction=0.0)
    ).to_json()
    assert math.isnan(result["metrics"]["after"]["test"]["rmse_mm"])
    job = store.create_job(cid, rid, "lm", {"test_fraction": 0.0})
    saved = store.save_result(job["id"], result)
    json.dumps(saved, allow_nan=False)
    assert saved["result"]["metrics"]["after"]["test"]["rmse_mm"] is None
    assert saved["result"]["dh"] == result["dh"]
    latest = store.latest_calibrated_model(rid)
    assert latest is not None
    assert latest["dh"] == result["dh"] and latest["tool_mm"] == result["tool_mm"]
    assert latest["metrics"]["train"] == result["metrics"]["after"]["train"]
    assert latest["method"] == "lm" and latest["robot"] == ROBOT


# ----------------------------------------------------------------------------- events
def test_events_record_filter_and_follow(store: Store, campaign: dict[str, Any]) -> None:
    store.record_event("sampler_started", None, "sampler up")
    store.record_event("link_down", "indicator", "timeout", {"frames_hex": ["01 03"],
                                                            "raw": b"\x01"})  # fmt: skip
    store.record_rejection(campaign["id"], "moving", "q2 moved 0.3 deg", "robot")
    store.record_rejection(999, "stale", "indicator reading 2.1 s old", "indicator")
    store.record_event("link_up", "indicator", "reconnected", {"age_s": math.inf})
    events = store.list_events()
    assert [e["kind"] for e in events] == ["sampler_started", "link_down", "capture_rejected",
                                           "capture_rejected", "link_up"]  # fmt: skip
    assert events[1]["detail"] == {"frames_hex": ["01 03"], "raw": str(b"\x01")}
    assert events[4]["detail"] == {"age_s": None}
    rejected = store.list_events(kind="capture_rejected")
    assert [e["campaign_id"] for e in rejected] == [campaign["id"], 999]
    assert rejected[0]["detail"] == {"reason": "moving", "detail": "q2 moved 0.3 deg"}
    assert rejected[0]["message"] == "moving: q2 moved 0.3 deg"
    assert rejected[0]["device"] == "robot"
    assert [e["kind"] for e in store.list_events(limit=2)] == ["capture_rejected", "link_up"]
    after = store.list_events(since_id=events[1]["id"], limit=2)
    assert [e["id"] for e in after] == [events[2]["id"], events[3]["id"]]
    assert store.list_events(campaign_id=campaign["id"]) == rejected[:1]
    with pytest.raises(StoreInvalid, match="limit"):
        store.list_events(limit=0)


# ------------------------------------------------------------------------- migrations
def test_version_1_file_is_migrated_on_open(tmp_path: Path) -> None:
    path = tmp_path / "old.sqlite3"
    conn = sqlite3.connect(path)
    assert apply_migrations(conn, upto=1) == 0
    model = json.dumps(builtin_model(ROBOT).to_dict())
    conn.execute("INSERT INTO robots VALUES (1, ?, 'dh', ?, 'builtin', 1.0)", (ROBOT, model))
    conn.execute("INSERT INTO campaigns VALUES (1, 'old', 1, '', 1, 'A', 2.0)")
    conn.execute(
        "INSERT INTO samples (id, campaign_id, q1, q2, q3, q4, q5, q6, length_mm, anchor, "
        "source, created_at) VALUES (1, 1, 1, 2, 90, 4, 5, 6, 432.1, 'A', 'import', 3.0)"
    )
    conn.commit()
    tables = {r[0] for r in conn.execute("SELECT name FROM sqlite_master WHERE type='table'")}
    assert "jobs" not in tables
    conn.close()

    with Store(path) as s:
        assert s.schema_version == SCHEMA_VERSION == 2
        sample = s.get_sample(1)
        assert sample is not None and sample["length_mm"] == 432.1
        assert sample["pose_group"] is None
        assert [c["id"] for c in s.auto_capture_campaigns()] == [1]
        assert s.ensure_builtin_robot(ROBOT)["id"] == 1
        job = s.create_job(1, 1, "lm", {})  # tables of version 2 work
        s.record_event("sampler_started", None, "up")
        assert s.save_result(job["id"], fake_result(0.0))["job_id"] == job["id"]
        assert s.integrity_check() == "ok"
    with sqlite3.connect(path) as conn:
        versions = [r[0] for r in conn.execute("SELECT version FROM schema_version ORDER BY 1")]
    assert versions == [1, 2]


def test_newer_file_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "db.sqlite3"
    Store(path).close()
    with sqlite3.connect(path) as conn:
        conn.execute("INSERT INTO schema_version VALUES (99, 'from the future', 0)")
    with pytest.raises(StoreError, match=r"schema version 99 is newer than this cablecal "
                       r"supports \(2\)"):  # fmt: skip
        Store(path)
    with pytest.raises(StoreError, match="99 is newer"):
        Store(path, readonly=True)


def test_foreign_database_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "other.sqlite3"
    with sqlite3.connect(path) as conn:
        conn.execute("CREATE TABLE things (x)")
    with pytest.raises(StoreError, match="not a cablecal database"):
        Store(path)
    garbage = tmp_path / "garbage.sqlite3"
    garbage.write_bytes(b"this is not sqlite at all" * 100)
    with pytest.raises(StoreError, match="cannot open the database"):
        Store(garbage)


def test_read_only_store(tmp_path: Path) -> None:
    path = tmp_path / "db.sqlite3"
    with pytest.raises(StoreError, match="no such database file"):
        Store(path, readonly=True)
    assert not path.exists()
    with Store(path) as s:
        cid = s.create_campaign("c", s.ensure_builtin_robot(ROBOT)["id"])["id"]
        s.store_capture(cid, make_capture((0, 0, 90, 0, 0, 0), 500.0))
        with Store(path, readonly=True) as ro:  # next to the writer
            assert len(ro.list_samples(cid)) == 1
            with pytest.raises(StoreError, match="read-only"):
                ro.record_event("x", None, "y")
    old = tmp_path / "old.sqlite3"
    conn = sqlite3.connect(old)
    apply_migrations(conn, upto=1)
    conn.close()
    with pytest.raises(StoreError, match="older than 2"):
        Store(old, readonly=True)


# ------------------------------------------------------------------ crash, concurrency
CRASH_WRITER = textwrap.dedent(
    """
    import sys
    from daemon.capture import Capture, RawReading
    from daemon.store import Store

    store = Store(sys.argv[1])
    campaign_id = int(sys.argv[2])
    for k in range(100_000):
        q = (0.0, 0.0, 90.0, 0.0, 0.0, k * 1e-3)
        raw = tuple(RawReading(1.0 + i, q, 500.0 + k) for i in range(10))
        cap = Capture(q, (0.0,) * 6, 500.0 + k % 1000, 0.0, 10, "A", 1.0, 2.0, "auto", raw)
        row = store.store_capture(campaign_id, cap)
        print(row["id"], flush=True)  # acknowledged only after store_capture returned
    """
)


def test_acknowledged_captures_survive_sigkill(tmp_path: Path) -> None:
    path = tmp_path / "state" / "cablecal.sqlite3"
    with Store(path) as s:
        cid = s.create_campaign("crash", s.ensure_builtin_robot(ROBOT)["id"])["id"]
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.Popen(
        [sys.executable, "-c", CRASH_WRITER, str(path), str(cid)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env=env,
        cwd=REPO,
    )
    assert proc.stdout is not None
    acknowledged: list[int] = []
    deadline = time.monotonic() + 30.0
    try:
        while len(acknowledged) < 200 and time.monotonic() < deadline:
            line = proc.stdout.readline()
            if not line:
                break
            acknowledged.append(int(line))
        assert len(acknowledged) >= 200, proc.stderr.read().decode() if proc.stderr else ""
    finally:
        proc.send_signal(signal.SIGKILL)
        rest, _ = proc.communicate(timeout=10)
    assert proc.returncode == -signal.SIGKILL
    # Lines the child wrote before dying were acknowledged too; a torn last line was not.
    complete = rest.decode().split("\n")[:-1]
    acknowledged += [int(v) for v in complete]

    with Store(path) as s:
        assert s.integrity_check() == "ok"
        stored = {r["id"] for r in s.list_samples(cid)}
        assert set(acknowledged) <= stored
        assert len(stored) - len(acknowledged) <= 1  # at most the one being written
        for sid in acknowledged[-3:]:
            assert len(s.raw_readings(sid)) == 10
        assert s.store_capture(cid, make_capture((0, 0, 90, 0, 0, 0), 500.0))["id"] > max(stored)


def test_concurrent_writers_lose_nothing(store: Store, campaign: dict[str, Any]) -> None:
    cid = campaign["id"]
    n_threads, per_thread = 4, 25
    barrier = threading.Barrier(n_threads + 2)
    ids: dict[int, list[int]] = {t: [] for t in range(n_threads)}
    errors: list[BaseException] = []

    def capture_writer(t: int) -> None:
        try:
            barrier.wait()
            for k in range(per_thread):
                cap = make_capture((t, 0.0, 90.0, 0.0, 0.0, k), 400.0 + t, n_raw=4)
                ids[t].append(int(store.store_capture(cid, cap)["id"]))
        except BaseException as exc:  # reported below
            errors.append(exc)

    def event_writer() -> None:
        try:
            barrier.wait()
            for k in range(per_thread):
                store.record_event("device_error", "indicator", f"timeout {k}")
        except BaseException as exc:
            errors.append(exc)

    threads = [threading.Thread(target=capture_writer, args=(t,)) for t in range(n_threads)]
    threads.append(threading.Thread(target=event_writer))
    for th in threads:
        th.start()
    barrier.wait()
    while any(th.is_alive() for th in threads[:n_threads]):  # readers in parallel
        store.list_campaigns()
        store.poses_deg(cid)
    for th in threads:
        th.join(timeout=30)
    assert not errors, errors
    all_ids = [i for t in ids.values() for i in t]
    assert len(all_ids) == len(set(all_ids)) == n_threads * per_thread
    assert {r["id"] for r in store.list_samples(cid)} == set(all_ids)
    for t in range(n_threads):  # each thread's samples are its own, in its order
        rows = [store.get_sample(i) for i in ids[t]]
        assert [r["q6"] for r in rows if r] == list(range(per_thread))
        assert all(r is not None and r["q1"] == t for r in rows)
    with sqlite3.connect(store.path) as conn:
        n_raw = conn.execute("SELECT count(*) FROM raw_readings").fetchone()[0]
    assert n_raw == 4 * n_threads * per_thread
    assert len(store.list_events(kind="device_error", limit=1000)) == per_thread
    assert store.integrity_check() == "ok"


# -------------------------------------------------------------------------------- CLI
@pytest.fixture
def cli() -> typer.Typer:
    app = typer.Typer()

    @app.callback()
    def root() -> None:
        """cablecal (test root)."""

    cli_db.register(app)
    return app


def test_cli_db_export_csv_and_json(
    tmp_path: Path, cli: typer.Typer, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv("CABLECAL_DB_PATH", raising=False)
    path = tmp_path / "db.sqlite3"
    with Store(path) as s:
        cid = s.create_campaign("line 3", s.ensure_builtin_robot(ROBOT)["id"])["id"]
        s.import_csv(cid, csv_text(12, groups=True))
        s.store_capture(cid, make_capture((1, 2, 90, 4, 5, 6), 654.321))
        expected_csv = s.export_csv(cid)
    runner = CliRunner()

    result = runner.invoke(cli, ["db", "export", str(cid), "--format", "csv", "--db", str(path)])
    assert result.exit_code == 0, result.output
    assert result.stdout == expected_csv
    assert len(parse_samples_csv(result.stdout)) == 13

    out = tmp_path / "out" / "c.json"
    out.parent.mkdir()
    result = runner.invoke(
        cli, ["db", "export", "line 3", "--format", "json", "--out", str(out), "--raw"],
        env={"CABLECAL_DB_PATH": str(path)},
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    data = json.loads(out.read_text(encoding="utf-8"))
    assert data["campaign"]["name"] == "line 3" and len(data["samples"]) == 13
    assert len(data["samples"][-1]["raw_readings"]) == 3

    result = runner.invoke(cli, ["db", "export", "77", "--db", str(path)])
    assert result.exit_code == cli_db.EXIT_NOT_FOUND
    assert "campaign 77 not found" in result.output
    result = runner.invoke(cli, ["db", "export", "1", "--db", str(tmp_path / "none.sqlite3")])
    assert result.exit_code == cli_db.EXIT_DB_ERROR
    assert "no such database file" in result.output
    assert not (tmp_path / "none.sqlite3").exists()
    result = runner.invoke(cli, ["db", "export", "1", "--format", "xml", "--db", str(path)])
    assert result.exit_code == 2
