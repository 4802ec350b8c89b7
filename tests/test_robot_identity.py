"""Issue 32 item 1: a robot is a physical robot. A robot has its own name and a model;
calibrations, checks and drift history belong to it; two robots of one model are two robots,
the same name is the same robot again; a store of the old schema (version 6, where a robot was
its model's name) migrates without losing a sample, job, result, plan or check."""

from __future__ import annotations

import json
import sqlite3
from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from test_service import AUTH, TOKEN, FakeSampler, _settings

from calib.default_robot import DEFAULT_ROBOT_MODEL
from calib.models import BUILTIN_MODELS, builtin_model
from daemon.api.main import create_app
from daemon.store import SCHEMA_VERSION, Store, StoreConflict

#: The schema of version 6 as its migrations left it (written out: the test must not build
#: the old store with today's code).
OLD_DDL_V6 = """
CREATE TABLE schema_version (version INTEGER PRIMARY KEY, description TEXT NOT NULL,
    applied_at REAL NOT NULL);
CREATE TABLE robots (id INTEGER PRIMARY KEY, name TEXT NOT NULL CHECK (name <> ''),
    convention TEXT NOT NULL CHECK (convention IN ('dh', 'mdh')), model_json TEXT NOT NULL,
    source TEXT NOT NULL CHECK (source IN ('builtin', 'uploaded')), created_at REAL NOT NULL,
    current_identification_id INTEGER REFERENCES jobs(id));
CREATE UNIQUE INDEX robots_builtin_name ON robots(name) WHERE source = 'builtin';
CREATE TABLE campaigns (id INTEGER PRIMARY KEY, name TEXT NOT NULL CHECK (name <> ''),
    robot_id INTEGER NOT NULL REFERENCES robots(id), notes TEXT NOT NULL DEFAULT '',
    auto_capture INTEGER NOT NULL DEFAULT 0 CHECK (auto_capture IN (0, 1)),
    auto_anchor TEXT NOT NULL DEFAULT 'A' CHECK (auto_anchor <> ''), created_at REAL NOT NULL);
CREATE INDEX campaigns_robot_id ON campaigns(robot_id);
CREATE TABLE samples (id INTEGER PRIMARY KEY,
    campaign_id INTEGER NOT NULL REFERENCES campaigns(id),
    q1 REAL NOT NULL, q2 REAL NOT NULL, q3 REAL NOT NULL, q4 REAL NOT NULL, q5 REAL NOT NULL,
    q6 REAL NOT NULL, length_mm REAL NOT NULL, anchor TEXT NOT NULL CHECK (anchor <> ''),
    q1_std REAL, q2_std REAL, q3_std REAL, q4_std REAL, q5_std REAL, q6_std REAL,
    length_std_mm REAL, count INTEGER CHECK (count IS NULL OR count >= 1), t_start REAL,
    t_end REAL, mode TEXT CHECK (mode IS NULL OR mode IN ('manual', 'auto')),
    excluded INTEGER NOT NULL DEFAULT 0 CHECK (excluded IN (0, 1)), excluded_reason TEXT,
    source TEXT NOT NULL CHECK (source IN ('capture', 'import')), created_at REAL NOT NULL,
    pose_group TEXT);
CREATE INDEX samples_campaign_id ON samples(campaign_id);
CREATE TABLE raw_readings (id INTEGER PRIMARY KEY,
    sample_id INTEGER NOT NULL REFERENCES samples(id), t_wall REAL NOT NULL,
    q1 REAL NOT NULL, q2 REAL NOT NULL, q3 REAL NOT NULL, q4 REAL NOT NULL, q5 REAL NOT NULL,
    q6 REAL NOT NULL, length_mm REAL NOT NULL);
CREATE INDEX raw_readings_sample_id ON raw_readings(sample_id);
CREATE TABLE jobs (id INTEGER PRIMARY KEY, campaign_id INTEGER NOT NULL REFERENCES campaigns(id),
    robot_id INTEGER NOT NULL REFERENCES robots(id), method TEXT NOT NULL CHECK (method <> ''),
    options_json TEXT NOT NULL DEFAULT '{}', status TEXT NOT NULL DEFAULT 'queued'
    CHECK (status IN ('queued', 'running', 'succeeded', 'failed', 'cancelled')),
    progress REAL NOT NULL DEFAULT 0 CHECK (progress >= 0 AND progress <= 1),
    message TEXT NOT NULL DEFAULT '', error TEXT, created_at REAL NOT NULL, started_at REAL,
    finished_at REAL, interrupted INTEGER NOT NULL DEFAULT 0 CHECK (interrupted IN (0, 1)),
    iteration INTEGER CHECK (iteration IS NULL OR iteration >= 0), cost_rms_mm REAL);
CREATE INDEX jobs_campaign_id ON jobs(campaign_id);
CREATE INDEX jobs_robot_id ON jobs(robot_id);
CREATE INDEX jobs_status ON jobs(status);
CREATE TABLE results (id INTEGER PRIMARY KEY, job_id INTEGER NOT NULL UNIQUE REFERENCES jobs(id),
    campaign_id INTEGER NOT NULL REFERENCES campaigns(id),
    robot_id INTEGER NOT NULL REFERENCES robots(id), result_json TEXT NOT NULL,
    accepted INTEGER NOT NULL DEFAULT 1 CHECK (accepted IN (0, 1)), created_at REAL NOT NULL);
CREATE INDEX results_campaign_id ON results(campaign_id);
CREATE INDEX results_robot_id ON results(robot_id);
CREATE TABLE events (id INTEGER PRIMARY KEY, t_wall REAL NOT NULL,
    kind TEXT NOT NULL CHECK (kind <> ''), device TEXT, campaign_id INTEGER,
    message TEXT NOT NULL DEFAULT '', detail_json TEXT);
CREATE INDEX events_kind ON events(kind);
CREATE INDEX events_campaign_id ON events(campaign_id);
CREATE TABLE plans (id INTEGER PRIMARY KEY, campaign_id INTEGER NOT NULL REFERENCES campaigns(id),
    robot_id INTEGER NOT NULL REFERENCES robots(id), options_json TEXT NOT NULL,
    summary_json TEXT NOT NULL, poses_json TEXT NOT NULL, created_at REAL NOT NULL);
CREATE INDEX plans_campaign_id ON plans(campaign_id);
CREATE TABLE check_poses (robot_id INTEGER PRIMARY KEY REFERENCES robots(id),
    poses_json TEXT NOT NULL, updated_at REAL NOT NULL);
CREATE TABLE checks (id INTEGER PRIMARY KEY, robot_id INTEGER NOT NULL REFERENCES robots(id),
    campaign_id INTEGER NOT NULL REFERENCES campaigns(id),
    result_id INTEGER NOT NULL REFERENCES results(id),
    trigger TEXT NOT NULL CHECK (trigger IN ('manual', 'schedule')),
    status TEXT NOT NULL CHECK (status IN ('running', 'ok', 'drift', 'failed')),
    refit_anchor INTEGER NOT NULL CHECK (refit_anchor IN (0, 1)),
    threshold_mm REAL NOT NULL CHECK (threshold_mm > 0), rms_mm REAL, mae_mm REAL, max_mm REAL,
    n INTEGER, error TEXT, started_at REAL NOT NULL, finished_at REAL, poses_json TEXT NOT NULL,
    detail_json TEXT);
CREATE INDEX checks_robot_id ON checks(robot_id);
CREATE INDEX checks_status ON checks(status);
CREATE INDEX samples_campaign_anchor ON samples(campaign_id, excluded, anchor);
"""

UPLOADED = "abb-irb4600-60-205"


def _model_json(name: str) -> str:
    data = builtin_model(DEFAULT_ROBOT_MODEL).to_dict()
    data["name"] = name
    return json.dumps(data)


def _old_store(path: Path) -> dict[str, list[tuple[object, ...]]]:
    """A version-6 store: the built-in robot and the same uploaded model twice (robots 2 and
    3: the old "each upload makes a robot"), a campaign on each, 30 samples with raw
    readings, a job and accepted result per robot, a plan and a check. Returns the rows the
    migrated store must still hold."""
    conn = sqlite3.connect(path, isolation_level=None)
    conn.executescript(OLD_DDL_V6)
    for v in range(1, 7):
        conn.execute("INSERT INTO schema_version VALUES (?, ?, 0)", (v, f"step {v}"))
    robots = [
        (1, DEFAULT_ROBOT_MODEL, "builtin"),
        (2, UPLOADED, "uploaded"),
        (3, UPLOADED, "uploaded"),
    ]
    for rid, name, source in robots:
        conn.execute(
            "INSERT INTO robots (id, name, convention, model_json, source, created_at) "
            "VALUES (?, ?, 'dh', ?, ?, ?)",
            (rid, name, _model_json(name), source, float(rid)),
        )
        conn.execute(
            "INSERT INTO campaigns (id, name, robot_id, created_at) VALUES (?, ?, ?, 0)",
            (rid, f"cell {rid}", rid),
        )
    sid = 0
    for cid in (1, 2, 3):
        for k in range(10):
            sid += 1
            q = [0.5 * sid, -60.0 + k, 200.0, -170.0, 40.0 + cid, 60.0]
            conn.execute(
                "INSERT INTO samples (id, campaign_id, q1, q2, q3, q4, q5, q6, length_mm, "
                "anchor, excluded, source, created_at) VALUES (?,?,?,?,?,?,?,?,?,?,?,?,0)",
                (sid, cid, *q, 1000.0 + sid, "A" if k < 7 else "A2", k == 3, "capture"),
            )
            conn.execute(
                "INSERT INTO raw_readings (sample_id, t_wall, q1, q2, q3, q4, q5, q6, "
                "length_mm) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
                (sid, float(sid), *q, 1000.0 + sid),
            )
    result = {"method": "ukf-vslm", "dh": [], "tool_mm": [0, 0, 0], "convention": "dh"}
    for rid in (1, 2, 3):
        conn.execute(
            "INSERT INTO jobs (id, campaign_id, robot_id, method, status, created_at) "
            "VALUES (?, ?, ?, 'ukf-vslm', 'succeeded', 0)",
            (rid, rid, rid),
        )
        conn.execute(
            "INSERT INTO results (id, job_id, campaign_id, robot_id, result_json, created_at) "
            "VALUES (?, ?, ?, ?, ?, 0)",
            (rid, rid, rid, rid, json.dumps(result)),
        )
        conn.execute("UPDATE robots SET current_identification_id = ? WHERE id = ?", (rid, rid))
    conn.execute(
        "INSERT INTO plans (campaign_id, robot_id, options_json, summary_json, poses_json, "
        "created_at) VALUES (1, 1, '{}', '{}', '[]', 0)"
    )
    conn.execute(
        "INSERT INTO checks (robot_id, campaign_id, result_id, trigger, status, refit_anchor, "
        "threshold_mm, started_at, poses_json) VALUES (2, 2, 2, 'manual', 'ok', 1, 0.5, 0, '[]')"
    )
    keep = {
        t: conn.execute(f"SELECT * FROM {t} ORDER BY id").fetchall()
        for t in ("samples", "raw_readings", "jobs", "results", "plans", "checks", "campaigns")
    }
    conn.close()
    return keep


def test_an_old_store_migrates_without_losing_a_row(tmp_path: Path) -> None:
    path = tmp_path / "old.sqlite3"
    before = _old_store(path)
    with Store(path) as store:
        conn = store.conn
        for table, rows in before.items():
            after = conn.execute(f"SELECT * FROM {table} ORDER BY id").fetchall()
            assert after == rows, table  # every sample, raw reading, job, result, plan, check
        assert conn.execute("SELECT max(version) FROM schema_version").fetchone()[0] == (
            SCHEMA_VERSION
        )
        robots = {r["id"]: r for r in store.list_robots()}
        # the oldest keeps its name; the later duplicate gets a name of its own, not merged
        assert [robots[i]["name"] for i in (1, 2, 3)] == [
            DEFAULT_ROBOT_MODEL,
            UPLOADED,
            f"{UPLOADED} (robot 3)",
        ]
        assert [robots[i]["model_name"] for i in (1, 2, 3)] == [
            DEFAULT_ROBOT_MODEL,
            UPLOADED,
            UPLOADED,
        ]
        # calibrations stay their robots'
        assert [robots[i]["current_identification_id"] for i in (1, 2, 3)] == [1, 2, 3]
        assert store.calibrated_model(3)["job_id"] == 3
        assert len(store.list_samples(2)) == 10 and store.campaign(3)["robot_id"] == 3
        assert store.campaign(3)["robot_name"] == f"{UPLOADED} (robot 3)"
        # the built-in robot is found again, not made anew
        assert store.ensure_builtin_robot(DEFAULT_ROBOT_MODEL)["id"] == 1


def test_two_robots_of_one_model_and_the_same_robot_again(tmp_path: Path) -> None:
    with Store(tmp_path / "s.sqlite3") as store:
        model = builtin_model(DEFAULT_ROBOT_MODEL)
        a, new_a = store.ensure_robot("cell 4 / SN 1001", model, "builtin")
        b, new_b = store.ensure_robot("cell 5 / SN 1002", model, "builtin")
        again, new_again = store.ensure_robot(" cell 4 / SN 1001 ", model, "builtin")
        assert (new_a, new_b, new_again) == (True, True, False)
        assert a["id"] != b["id"] and again["id"] == a["id"]
        assert a["model_name"] == b["model_name"] == DEFAULT_ROBOT_MODEL
        other = builtin_model(DEFAULT_ROBOT_MODEL).to_dict()
        other["name"], other["tool_mm"] = "other", [0.0, 0.0, 100.0]
        from calib.models import model_from_mapping

        with pytest.raises(StoreConflict, match="give this robot its own name"):
            store.ensure_robot("cell 4 / SN 1001", model_from_mapping(other))


@pytest.fixture(scope="module")
def client(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TestClient]:
    app = create_app(_settings(tmp_path_factory.mktemp("ids")), TOKEN, sampler_factory=FakeSampler)
    with TestClient(app) as c:
        yield c


def _toml(name: str, tool_z_mm: float = 0.0) -> str:
    data = builtin_model(DEFAULT_ROBOT_MODEL).to_dict()
    lines = [f'name = "{name}"', f'convention = "{data["convention"]}"']
    lines.append(f"tool_mm = [0.0, 0.0, {tool_z_mm}]")
    for j in data["joints"]:
        lines.append("[[joints]]")
        lines += [f"{k} = {json.dumps(v)}" for k, v in j.items()]
    return "\n".join(lines) + "\n"


def _campaign(client: TestClient, **body: object) -> dict[str, object]:
    r = client.post("/api/v1/campaigns", json={"name": "c", **body}, headers=AUTH)
    assert r.status_code == 201, r.text
    return dict(r.json())


def test_campaigns_name_their_robot(client: TestClient) -> None:
    one = _campaign(client, robot="cell 4 SN 1001", robot_model=DEFAULT_ROBOT_MODEL)
    two = _campaign(client, robot="cell 5 SN 1002", robot_model=DEFAULT_ROBOT_MODEL)
    again = _campaign(client, robot="cell 4 SN 1001", robot_model=DEFAULT_ROBOT_MODEL)
    by_id = _campaign(client, robot_id=two["robot_id"])
    assert one["robot_id"] != two["robot_id"]
    assert again["robot_id"] == one["robot_id"] and by_id["robot_id"] == two["robot_id"]
    assert one["robot_name"] == "cell 4 SN 1001"
    assert one["robot_model_name"] == DEFAULT_ROBOT_MODEL
    # a TOML model file, twice: one robot (the old walk got robot 6 instead of robot 2)
    file = {"filename": "irb4600.toml", "text": _toml(UPLOADED)}
    first = _campaign(client, robot="cell 7 IRB 4600", robot_model_file=file)
    second = _campaign(client, robot="cell 7 IRB 4600", robot_model_file=file)
    unnamed = _campaign(client, robot_model_file=file)
    assert first["robot_id"] == second["robot_id"]
    assert unnamed["robot_name"] == UPLOADED and unnamed["robot_id"] != first["robot_id"]
    assert first["robot_model_name"] == UPLOADED
    # the name of another model's robot: 409, naming what to do
    changed = {"filename": "irb4600.toml", "text": _toml(UPLOADED, tool_z_mm=150.0)}
    r = client.post(
        "/api/v1/campaigns",
        json={"name": "c", "robot": "cell 7 IRB 4600", "robot_model_file": changed},
        headers=AUTH,
    )
    assert r.status_code == 409 and "its own name" in r.json()["detail"], r.text
    listed = client.get("/api/v1/robots", headers=AUTH).json()
    names = [r["name"] for r in listed]
    assert len(names) == len(set(names)) and {"cell 4 SN 1001", "cell 7 IRB 4600"} <= set(names)


def test_robot_routes(client: TestClient) -> None:
    models = client.get("/api/v1/robots/models", headers=AUTH).json()
    assert [m["name"] for m in models] == sorted(BUILTIN_MODELS)
    assert [m["name"] for m in models if m["default"]] == [DEFAULT_ROBOT_MODEL]
    body = {"name": "line 2 SN 77", "model": DEFAULT_ROBOT_MODEL}
    made = client.post("/api/v1/robots", json=body, headers=AUTH)
    found = client.post("/api/v1/robots", json=body, headers=AUTH)
    assert (made.status_code, found.status_code) == (201, 200)
    assert made.json()["id"] == found.json()["id"]
    json_file = {
        "filename": "m.json",
        "text": json.dumps(builtin_model(DEFAULT_ROBOT_MODEL).to_dict()),
    }
    r = client.post(
        "/api/v1/robots", json={"name": "line 3", "model_file": json_file}, headers=AUTH
    )
    assert r.status_code == 201 and r.json()["source"] == "uploaded", r.text
    bad = [
        ({"name": "x", "model_file": {"filename": "m.txt", "text": ""}}, ".toml or .json"),
        ({"name": "x", "model_file": {"filename": "m.toml", "text": "name = "}}, "m.toml"),
        ({"name": "x"}, "give a model or a model_file"),
        ({"name": "x", "model": "no-such-arm"}, "unknown built-in model"),
    ]
    for payload, words in bad:
        r = client.post("/api/v1/robots", json=payload, headers=AUTH)
        assert r.status_code == 422 and words in r.text, (payload, r.text)
