"""The store's file: WAL and full sync, migrations, read-only open, SIGKILL, concurrent writers."""

from __future__ import annotations

import json
import os
import signal
import sqlite3
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path
from typing import Any

import pytest
from _store_helpers import REPO, ROBOT, fake_result, make_capture

from calib.models import builtin_model
from daemon.store import MIGRATIONS, SCHEMA_VERSION, Store, StoreError, apply_migrations


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
    assert {
        "robots",
        "campaigns",
        "samples",
        "raw_readings",
        "jobs",
        "results",
        "events",
        "schema_version",
    } <= tables
    assert {
        "samples_campaign_id",
        "raw_readings_sample_id",
        "events_kind",
        "jobs_campaign_id",
        "results_robot_id",
    } <= indexes


def test_closed_store_raises_store_error(tmp_path: Path) -> None:
    s = Store(tmp_path / "db.sqlite3")
    s.close()
    s.close()  # idempotent
    with pytest.raises(StoreError, match="closed"):
        s.list_campaigns()


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
        assert s.schema_version == SCHEMA_VERSION == len(MIGRATIONS)
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
    assert versions == list(range(1, SCHEMA_VERSION + 1))


def test_newer_file_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "db.sqlite3"
    Store(path).close()
    with sqlite3.connect(path) as conn:
        conn.execute("INSERT INTO schema_version VALUES (99, 'from the future', 0)")
    with pytest.raises(
        StoreError,
        match=r"schema version 99 is newer than this cablecal "
        rf"supports \({SCHEMA_VERSION}\)",
    ):
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
    with pytest.raises(StoreError, match=f"older than {SCHEMA_VERSION}"):
        Store(old, readonly=True)


# ------------------------------------------------------------------ crash, concurrency
CRASH_WRITER = textwrap.dedent(
    """
    import sys
    from daemon.sampler.capture import Capture, RawReading
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


def test_migration_6_makes_the_newest_accepted_result_current(tmp_path: Path) -> None:
    """A file from before the current calibration (schema 5): each robot's newest accepted
    result becomes its current one; a robot without one stays uncalibrated."""
    path = tmp_path / "v5.sqlite3"
    conn = sqlite3.connect(path)
    apply_migrations(conn, upto=5)
    t = 1.0e9
    conn.execute(
        "INSERT INTO robots (id, name, convention, model_json, source, created_at) "
        "VALUES (1, 'r', 'dh', '{}', 'uploaded', ?), (2, 'q', 'dh', '{}', 'uploaded', ?)",
        (t, t),
    )
    conn.execute(
        "INSERT INTO campaigns (id, name, robot_id, created_at) VALUES (1, 'c', 1, ?)", (t,)
    )
    for job_id, accepted in ((1, 1), (2, 1), (3, 0)):
        conn.execute(
            "INSERT INTO jobs (id, campaign_id, robot_id, method, status, created_at) "
            "VALUES (?, 1, 1, 'lm', 'succeeded', ?)",
            (job_id, t),
        )
        conn.execute(
            "INSERT INTO results (job_id, campaign_id, robot_id, result_json, accepted, "
            "created_at) VALUES (?, 1, 1, '{}', ?, ?)",
            (job_id, accepted, t),
        )
    conn.commit()
    conn.close()
    with Store(path) as s:
        assert s.robot(1)["current_identification_id"] == 2
        assert s.robot(2)["current_identification_id"] is None
        assert [j["current"] for j in s.list_jobs(1)] == [False, True, False]
        assert s.job(1)["progress"] == {"fraction": 0.0, "iteration": None, "cost_rms_mm": None}
