"""One name per meaning (issue 33 item 2): the check that a robot holds its calibration is the
hold check everywhere; the old names stay readable for one release. The config section
``[drift]`` is read as ``[hold_check]`` with a warning in the log, the gauges are exported
under both names, and a store written before (verdict ``drift``, events ``drift`` and
``drift_check``, check campaigns noted "drift check (…)") reads as the new names."""

from __future__ import annotations

import json
import logging
import sqlite3
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from prometheus_client import generate_latest
from test_service import AUTH, TOKEN, FakeSampler

from daemon import metrics
from daemon.api.main import create_app
from daemon.config import DEPRECATED_SECTIONS, Settings
from daemon.store import Store
from daemon.store.errors import StoreInvalid
from daemon.store.schema import apply_migrations


@pytest.fixture
def clean_env(monkeypatch: pytest.MonkeyPatch) -> None:
    import os

    for name in list(os.environ):
        if name.startswith("CABLECAL_"):
            monkeypatch.delenv(name)


@pytest.mark.usefixtures("clean_env")
def test_the_old_section_is_read_with_a_warning(tmp_path: Path) -> None:
    old = tmp_path / "old.toml"
    old.write_text("[drift]\ntimeout_s = 60.0\nn_poses = 5\n", encoding="utf-8")
    s = Settings.load(old)
    assert (s.hold_check.timeout_s, s.hold_check.n_poses) == (60.0, 5)
    (note,) = s.deprecations()
    assert "[drift] is deprecated" in note and "[hold_check]" in note
    assert DEPRECATED_SECTIONS["drift"][1] in note  # the release that stops reading it
    new = tmp_path / "new.toml"
    new.write_text("[hold_check]\ntimeout_s = 60.0\n", encoding="utf-8")
    assert Settings.load(new).deprecations() == []
    assert "drift" not in Settings.load(new).model_dump()


@pytest.mark.usefixtures("clean_env")
def test_the_new_name_wins_over_the_old(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    both = tmp_path / "both.toml"
    both.write_text(
        "[drift]\ntimeout_s = 60.0\nn_poses = 5\n[hold_check]\ntimeout_s = 90.0\n",
        encoding="utf-8",
    )
    s = Settings.load(both)
    assert (s.hold_check.timeout_s, s.hold_check.n_poses) == (90.0, 5)
    monkeypatch.setenv("CABLECAL_DRIFT__POSE_TOL_DEG", "0.25")  # the old environment name
    s = Settings()
    assert s.hold_check.pose_tol_deg == 0.25 and s.deprecations()


@pytest.mark.usefixtures("clean_env")
def test_the_daemon_logs_the_deprecation(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    settings = Settings(state_dir=tmp_path, api_token=TOKEN, drift={"timeout_s": 30})
    with (
        caplog.at_level(logging.WARNING, logger="cablecal.serve"),
        TestClient(create_app(settings, TOKEN, sampler_factory=FakeSampler)) as client,
    ):
        status = client.get("/api/v1/status", headers=AUTH)
    assert status.json()["hold_check"]["state"] == "none"
    assert any("[drift] is deprecated" in r.getMessage() for r in caplog.records)


def test_the_gauges_carry_both_names_until_the_old_ones_go() -> None:
    metrics.record_hold_check(4242, 0.125, 0.5)
    text = generate_latest(metrics.REGISTRY).decode()
    for new, old in metrics.DEPRECATED_HOLD_CHECK_NAMES.items():
        value = "0.125" if new.endswith("rms_mm") else "0.5"
        assert f'{new}{{robot="4242"}} {value}' in text
        assert f'{old}{{robot="4242"}} {value}' in text
        assert f"# HELP {old} Deprecated (removed in 0.3.0): {new}." in text


def _old_store(path: Path) -> None:
    """A version-7 store (before the rename) with a check judged ``drift``, one ``ok``, their
    events and a check campaign's notes."""
    conn = sqlite3.connect(path, isolation_level=None)
    conn.execute("PRAGMA foreign_keys = ON")
    apply_migrations(conn, upto=7)
    conn.execute(
        "INSERT INTO robots (id, name, model_name, convention, model_json, source, created_at)"
        " VALUES (1, 'cell 1', 'hsr-jr680', 'dh', '{}', 'builtin', 0)"
    )
    for cid, notes in ((1, ""), (2, "drift check (manual) against result 1")):
        conn.execute(
            "INSERT INTO campaigns (id, name, robot_id, notes, created_at) VALUES (?, ?, 1, ?, 0)",
            (cid, f"c{cid}", notes),
        )
    conn.execute(
        "INSERT INTO jobs (id, campaign_id, robot_id, method, status, created_at) "
        "VALUES (1, 1, 1, 'lm', 'succeeded', 0)"
    )
    conn.execute(
        "INSERT INTO results (id, job_id, campaign_id, robot_id, result_json, created_at) "
        "VALUES (1, 1, 1, 1, '{}', 0)"
    )
    for status in ("ok", "drift"):
        conn.execute(
            "INSERT INTO checks (robot_id, campaign_id, result_id, trigger, status, "
            "refit_anchor, threshold_mm, rms_mm, started_at, finished_at, poses_json) "
            "VALUES (1, 2, 1, 'manual', ?, 0, 0.1, 0.2, 0, 1, '[]')",
            (status,),
        )
    for kind, status in (("drift_check", "ok"), ("drift", "drift")):
        conn.execute(
            "INSERT INTO events (t_wall, kind, message, detail_json) VALUES (0, ?, 'm', ?)",
            (kind, json.dumps({"check_id": 1, "status": status})),
        )
    conn.close()


def test_an_old_store_reads_as_the_new_names(tmp_path: Path) -> None:
    path = tmp_path / "old.sqlite3"
    _old_store(path)
    with Store(path) as store:
        assert [c["status"] for c in store.list_checks(1)] == ["ok", "not_held"]
        events = {e["kind"]: e["detail"] for e in store.list_events()}
        assert events == {
            "hold_check": {"check_id": 1, "status": "ok"},
            "hold_check_not_held": {"check_id": 1, "status": "not_held"},
        }
        assert store.campaign(2)["notes"] == "hold check (manual) against result 1"
        assert store.campaign(1)["notes"] == ""
        # the rebuilt table holds the new verdict and refuses the old one
        check = store.create_check(
            1, 2, 1, trigger="manual", threshold_mm=0.1, refit_anchor=False, poses_deg=[[0.0] * 6]
        )
        with pytest.raises(StoreInvalid):
            store.finish_check(check["id"], "drift")  # type: ignore[arg-type]
        with pytest.raises(sqlite3.IntegrityError):
            store.conn.execute("UPDATE checks SET status = 'drift' WHERE id = ?", (check["id"],))
