"""The apply routes in-process: compensate, the calibrated model as a file, verify, check
poses and hold checks (401, 404, 422 bounds, happy paths). Captures of a check are written
into the store as the sampler would, with lengths of a synthetic true cell (unchanged, then
with one joint offset shifted)."""

from __future__ import annotations

import math
import time
import tomllib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import jsonschema
import numpy as np
import pytest
from fastapi.testclient import TestClient
from prometheus_client.parser import text_string_to_metric_families
from test_service import AUTH, TOKEN, FakeSampler

from calib.dataset import make_samples, samples_to_csv
from calib.models import builtin_model
from calib.synthetic import TrueCell, make_true_cell, noisy_lengths, random_poses_deg
from daemon.api.main import create_app
from daemon.config import Settings
from daemon.sampler.capture import Capture

NOISE_MM = 0.03
API = "/api/v1"


@pytest.fixture(scope="module")
def cell() -> TrueCell:
    return make_true_cell(builtin_model("hsr-jr680"))


@pytest.fixture(scope="module")
def client(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TestClient]:
    tmp = tmp_path_factory.mktemp("apply")
    settings = Settings(state_dir=tmp, api_token=TOKEN, hold_check={"timeout_s": 30})
    with TestClient(create_app(settings, TOKEN, sampler_factory=FakeSampler)) as c:
        yield c


def _campaign(client: TestClient, cell: TrueCell, n: int, seed: int) -> int:
    r = client.post(
        f"{API}/campaigns", json={"name": "c", "robot_model": "hsr-jr680"}, headers=AUTH
    )
    cid = int(r.json()["id"])
    rng = np.random.default_rng(seed)
    q = random_poses_deg(cell, n, rng)
    csv_text = samples_to_csv(make_samples(q, noisy_lengths(cell, q, rng, noise_mm=NOISE_MM)))
    r = client.post(
        f"{API}/campaigns/{cid}/samples/import",
        content=csv_text,
        headers={**AUTH, "Content-Type": "text/csv"},
    )
    assert r.status_code in (200, 201), r.text
    return cid


@pytest.fixture(scope="module")
def calibrated(client: TestClient, cell: TrueCell) -> dict[str, int]:
    """A robot with an accepted calibration: ``robot_id``, ``job_id``, ``campaign_id``."""
    cid = _campaign(client, cell, 80, seed=5)
    r = client.post(
        f"{API}/campaigns/{cid}/identifications",
        json={"method": "lm", "test_fraction": 0.2, "seed": 0},
        headers=AUTH,
    )
    job_id = r.json()["id"]
    deadline = time.monotonic() + 120
    while (job := client.get(f"{API}/identifications/{job_id}", headers=AUTH).json())[
        "status"
    ] not in ("succeeded", "failed"):
        assert time.monotonic() < deadline
        time.sleep(0.2)
    assert job["status"] == "succeeded", job
    if not job["accepted"]:  # the plausibility screen may hold it back: accept after review
        r = client.post(f"{API}/identifications/{job_id}/accept", headers=AUTH)
        assert r.status_code == 200 and r.json()["accepted"], r.text
    robot_id = client.get(f"{API}/campaigns/{cid}", headers=AUTH).json()["robot_id"]
    return {"robot_id": robot_id, "job_id": job_id, "campaign_id": cid}


def _uncalibrated_robot(client: TestClient) -> int:
    """A new robot of the model (its own name: the same name would be the calibrated one)."""
    n = len(client.get(f"{API}/robots", headers=AUTH).json())
    body = {"name": "u", "robot": f"uncalibrated {n + 1}", "robot_model": "hsr-jr680"}
    r = client.post(f"{API}/campaigns", json=body, headers=AUTH)
    return int(r.json()["robot_id"])


def _text(r: Any) -> str:
    """The messages and locations of a 422 (the list form), as one string."""
    return " ".join(f"{e['loc']} {e['msg']}" for e in r.json()["detail"])


def test_new_routes_need_the_token(client: TestClient, calibrated: dict[str, int]) -> None:
    rid, jid = calibrated["robot_id"], calibrated["job_id"]
    for method, url in (
        ("POST", f"/robots/{rid}/compensate"),
        ("PUT", f"/robots/{rid}/check-poses"),
        ("POST", f"/robots/{rid}/checks"),
        ("POST", f"/identifications/{jid}/verify"),
        ("GET", f"/robots/{rid}/checks"),
        ("GET", f"/robots/{rid}/check-poses"),
    ):
        r = client.request(method, API + url, json=[])
        assert r.status_code == 401, (method, url)


def test_compensate_json_and_csv(
    client: TestClient, cell: TrueCell, calibrated: dict[str, int]
) -> None:
    rid = calibrated["robot_id"]
    q = random_poses_deg(cell, 10, np.random.default_rng(9))
    body = [{f"q{j + 1}": float(v) for j, v in enumerate(row)} for row in q]
    r = client.post(
        f"{API}/robots/{rid}/compensate", json=body, headers=AUTH, params={"tool_mm": "0,0,40"}
    )
    assert r.status_code == 200, r.text
    out = r.json()
    assert out["summary"]["n"] == 10 and out["tool_mm"] == [0.0, 0.0, 40.0]
    assert "base z axis" in out["note"]
    corrected = np.array([[row[f"q{j}"] for j in range(1, 7)] for row in out["rows"]])
    assert 1e-3 < np.abs(corrected - q).max() < 5.0
    assert max(row["residual_mm"] for row in out["rows"]) < 0.01
    csv_body = "q1,q2,q3,q4,q5,q6\n" + "\n".join(",".join(f"{v}" for v in row) for row in q)
    r = client.post(
        f"{API}/robots/{rid}/compensate",
        content=csv_body,
        params={"tool_mm": "0,0,40"},
        headers={**AUTH, "Content-Type": "text/csv", "Accept": "text/csv"},
    )
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/csv")
    lines = r.text.strip().splitlines()
    assert lines[0].startswith("index,q1_nominal") and len(lines) == 11
    first = dict(zip(lines[0].split(","), lines[1].split(","), strict=True))
    assert float(first["q2"]) == pytest.approx(corrected[0, 1], abs=5e-4 + 1e-9)  # 0.001 deg


def test_compensate_errors_and_bounds(client: TestClient, calibrated: dict[str, int]) -> None:
    rid = calibrated["robot_id"]
    url = f"{API}/robots/{rid}/compensate"
    row = {f"q{j}": 10.0 for j in range(1, 7)}
    r = client.post(url, json=[row] * 10_001, headers=AUTH)
    assert r.status_code == 422 and "10000" in _text(r)
    r = client.post(url, json=[row, {**row, "q3": "x"}], headers=AUTH)
    assert r.status_code == 422 and r.json()["detail"][0]["loc"] == ["body", 1, "q3"], r.text
    r = client.post(
        url,
        content="q1,q2,q3,q4,q5,q6\n1,2,3,4,5,x\n",
        headers={**AUTH, "Content-Type": "text/csv"},
    )
    assert r.status_code == 422 and "line 2" in _text(r) and "q6" in _text(r)
    r = client.post(url, json=[row], headers=AUTH, params={"tool_mm": "1,2"})
    assert r.status_code == 422 and r.json()["detail"][0]["loc"] == ["query", "tool_mm"]
    # x,y,z without a seed: the default seed (middle of the joint limits), flags name joints
    r = client.post(url, json=[{"x": 1.0, "y": 2.0, "z": 3.0}], headers=AUTH)
    assert r.status_code == 200, r.text
    flags = r.json()["rows"][0]["flags"]
    assert all(
        f.split(":")[0] != "outside_limits" or f.startswith("outside_limits:J")
        for f in flags.split(";")
    )
    other = _uncalibrated_robot(client)
    r = client.post(f"{API}/robots/{other}/compensate", json=[row], headers=AUTH)
    assert r.status_code == 404 and "no accepted calibration" in r.json()["detail"]


BIG = 2**63  # one past SQLite's largest INTEGER


def test_ids_beyond_sqlite_integer_are_422(client: TestClient, calibrated: dict[str, int]) -> None:
    cid = calibrated["campaign_id"]
    for method, url, body in (
        ("POST", f"/robots/{BIG}/compensate", [{f"q{j}": 0.0 for j in range(1, 7)}]),
        ("PUT", f"/robots/{BIG}/check-poses", {"poses_deg": [[0.0] * 6] * 3}),
        ("GET", f"/robots/{BIG}/check-poses", None),
        ("POST", f"/robots/{BIG}/checks", None),
        ("GET", f"/robots/{BIG}/checks", None),
        ("GET", f"/robots/{BIG}/calibrated-model?format=toml", None),
        ("POST", f"/identifications/{BIG}/verify", {"campaign_id": cid}),
    ):
        r = client.request(method, API + url, json=body, headers=AUTH)
        assert r.status_code == 422, (method, url, r.text)
        assert r.json()["detail"][0]["loc"][0] == "path", r.text
    r = client.post(
        f"{API}/identifications/{calibrated['job_id']}/verify",
        json={"campaign_id": BIG},
        headers=AUTH,
    )
    assert r.status_code == 422 and r.json()["detail"][0]["loc"] == ["body", "campaign_id"]


def test_strings_booleans_and_non_finite_numbers_are_strict(
    client: TestClient, calibrated: dict[str, int]
) -> None:
    rid, jid = calibrated["robot_id"], calibrated["job_id"]
    url = f"{API}/robots/{rid}/compensate"
    row = {f"q{j}": 10.0 for j in range(1, 7)}
    for params, loc in (
        ({"tool_mm": "1," * 200 + "1"}, ["query", "tool_mm"]),
        ({"seed_deg": ""}, ["query", "seed_deg"]),
        ({"tool_mm": " "}, ["query", "tool_mm"]),
    ):
        r = client.post(url, json=[row], params=params, headers=AUTH)
        assert r.status_code == 422 and r.json()["detail"][0]["loc"] == loc, (params, r.text)
    for body, loc in (
        ([{**row, "q1": "10"}], ["body", 0, "q1"]),
        ([{**row, "q2": True}], ["body", 0, "q2"]),
        ([{**row, "note": "x"}], ["body", 0, "note"]),
        ([], ["body"]),
    ):
        r = client.post(url, json=body, headers=AUTH)
        assert r.status_code == 422 and r.json()["detail"][0]["loc"] == loc, (body, r.text)
    r = client.post(
        url,
        content=b'[{"q1": NaN, "q2": 0, "q3": 0, "q4": 0, "q5": 0, "q6": 0}]',
        headers={**AUTH, "Content-Type": "application/json"},
    )
    assert r.status_code == 422, r.text
    r = client.post(url, content=b"q1\n\xff\n", headers={**AUTH, "Content-Type": "text/csv"})
    assert r.status_code == 400 and "UTF-8" in r.json()["detail"], r.text
    r = client.post(
        f"{API}/identifications/{jid}/verify",
        json={"campaign_id": calibrated["campaign_id"], "refit_anchor": "yes"},
        headers=AUTH,
    )
    assert r.status_code == 422 and r.json()["detail"][0]["loc"] == ["body", "refit_anchor"]
    r = client.put(
        f"{API}/robots/{rid}/check-poses", json={"poses_deg": [["0"] * 6] * 3}, headers=AUTH
    )
    assert r.status_code == 422 and r.json()["detail"][0]["loc"][:2] == ["body", "poses_deg"]


def test_compensate_body_is_bounded_by_the_guard(
    client: TestClient, calibrated: dict[str, int]
) -> None:
    url = f"{API}/robots/{calibrated['robot_id']}/compensate"
    csv_body = "q1,q2,q3,q4,q5,q6\n" + "0,0,0,0,0,0\n" * (4 * 1024 * 1024 // 12 + 1)
    r = client.post(url, content=csv_body, headers={**AUTH, "Content-Type": "text/csv"})
    assert r.status_code == 413 and isinstance(r.json()["detail"], str), r.text


def test_calibrated_model_formats(client: TestClient, calibrated: dict[str, int]) -> None:
    rid = calibrated["robot_id"]
    url = f"{API}/robots/{rid}/calibrated-model"
    table = client.get(url, headers=AUTH)
    assert table.status_code == 200 and len(table.json()["dh"]) == 6  # the default stays
    toml = client.get(url, params={"format": "toml"}, headers=AUTH)
    assert toml.headers["content-type"].startswith("application/toml")
    assert 'filename="hsr-jr680-calibrated.toml"' in toml.headers["content-disposition"]
    joints = tomllib.loads(toml.text)["joints"]
    assert joints[1]["a_mm"] == pytest.approx(table.json()["dh"][1]["a_mm"], abs=1e-9)
    urdf = client.get(url, params={"format": "urdf"}, headers=AUTH)
    assert urdf.headers["content-type"].startswith("application/xml") and "<robot" in urdf.text
    js = client.get(url, params={"format": "json"}, headers=AUTH)
    assert js.headers["content-type"].startswith("application/json") and "joints" in js.json()
    assert client.get(url, params={"format": "step"}, headers=AUTH).status_code == 422
    # Issue 28, item 6: every answer is as the OpenAPI document declares it, media type and
    # body (the JSON model file was an undocumented body under the CalibratedModel schema).
    spec = client.get("/openapi.json").json()
    path = spec["paths"]["/api/v1/robots/{robot_id}/calibrated-model"]["get"]
    declared = path["responses"]["200"]["content"]
    for r in (table, toml, urdf, js):
        assert r.headers["content-type"].split(";")[0] in declared, r.headers["content-type"]
    schema = {**declared["application/json"]["schema"], "components": spec["components"]}
    for r in (table, js):
        jsonschema.validate(r.json(), schema)


def test_verify_route(client: TestClient, cell: TrueCell, calibrated: dict[str, int]) -> None:
    cid = _campaign(client, cell, 25, seed=11)
    url = f"{API}/identifications/{calibrated['job_id']}/verify"
    r = client.post(url, json={"campaign_id": cid}, headers=AUTH)
    assert r.status_code == 200, r.text
    out = r.json()
    assert out["metrics"]["n"] == 25 and len(out["residuals"]) == 25
    assert 0.5 * NOISE_MM < out["metrics"]["rmse_mm"] < 2 * NOISE_MM
    r = client.post(url, json={"campaign_id": cid, "refit_anchor": True}, headers=AUTH)
    assert r.status_code == 200 and r.json()["refit_anchor"] is True
    assert client.post(url, json={"campaign_id": 999999}, headers=AUTH).status_code == 404
    r = client.post(f"{API}/identifications/999999/verify", json={"campaign_id": cid}, headers=AUTH)
    assert r.status_code == 404
    assert client.post(url, json={"campaign": cid}, headers=AUTH).status_code == 422


def test_check_poses_default_and_user(client: TestClient, calibrated: dict[str, int]) -> None:
    rid = calibrated["robot_id"]
    url = f"{API}/robots/{rid}/check-poses"
    default = client.get(url, headers=AUTH).json()
    assert default["source"] == "default" and len(default["poses_deg"]) == 8
    samples = client.get(
        f"{API}/campaigns/{calibrated['campaign_id']}/samples", headers=AUTH
    ).json()
    q = {tuple(round(s[f"q{j}"], 9) for j in range(1, 7)) for s in samples}
    assert all(tuple(round(v, 9) for v in p) in q for p in default["poses_deg"])
    assert client.put(url, json={"poses_deg": [[0.0] * 6] * 2}, headers=AUTH).status_code == 422
    assert client.put(url, json={"poses_deg": [[0.0] * 5] * 3}, headers=AUTH).status_code == 422
    # a pose outside the model's joint limits: a 422 naming pose and joint, nothing stored
    bad = [list(p) for p in default["poses_deg"][:3]]
    bad[1][1] = -2307.5
    r = client.put(url, json={"poses_deg": bad}, headers=AUTH)
    assert r.status_code == 422, r.text
    assert "row 2, q2" in r.text and "joint limits" in r.text
    assert client.get(url, headers=AUTH).json()["source"] == "default"
    # poses stored before the check (an older daemon) cannot become a program: a 409 saying why
    store = client.app.state.cablecal.store  # type: ignore[attr-defined]
    store.set_check_poses(rid, bad)
    r = client.get(url, params={"format": "rapid"}, headers=AUTH)
    assert r.status_code == 409 and "row 2, q2" in r.text, r.text
    assert client.put(url, json={"poses_deg": default["poses_deg"]}, headers=AUTH).is_success
    assert client.get(url, params={"format": "rapid"}, headers=AUTH).status_code == 200
    other = _uncalibrated_robot(client)
    r = client.get(f"{API}/robots/{other}/check-poses", headers=AUTH)
    assert r.status_code == 404
    assert client.get(f"{API}/robots/999999/checks", headers=AUTH).status_code == 404


def _store_captures(client: TestClient, cid: int, q: np.ndarray, lengths: np.ndarray) -> None:
    store = client.app.state.cablecal.store  # type: ignore[attr-defined]
    now = time.time()
    for row, length in zip(q, lengths, strict=True):
        store.store_capture(
            cid,
            Capture(
                joints_deg=tuple(float(v) for v in row),
                joints_std_deg=(0.0,) * 6,  # type: ignore[arg-type]
                length_mm=float(length),
                length_std_mm=0.01,
                count=10,
                anchor="A",
                t_start_wall=now - 0.5,
                t_end_wall=now,
                mode="auto",
            ),
        )


def _wait_check(client: TestClient, rid: int, check_id: int) -> dict[str, Any]:
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        checks = client.get(f"{API}/robots/{rid}/checks", headers=AUTH).json()
        check = next(c for c in checks if c["id"] == check_id)
        if check["status"] != "running":
            return dict(check)
        time.sleep(0.2)
    raise AssertionError(f"check {check_id} still running")


def _gauge(client: TestClient, rid: int, name: str = "cablecal_hold_check_rms_mm") -> float:
    text = client.get("/metrics").text
    for family in text_string_to_metric_families(text):
        for s in family.samples:
            if s.name == name and s.labels == {"robot": str(rid)}:
                return float(s.value)
    return math.nan


def test_hold_checks_ok_then_not_held(
    client: TestClient, cell: TrueCell, calibrated: dict[str, int]
) -> None:
    rid = calibrated["robot_id"]
    poses = random_poses_deg(cell, 6, np.random.default_rng(21))
    r = client.put(
        f"{API}/robots/{rid}/check-poses", json={"poses_deg": poses.tolist()}, headers=AUTH
    )
    assert r.status_code == 200 and r.json()["source"] == "user"
    rng = np.random.default_rng(22)
    shifted_theta = cell.theta.copy()
    shifted_theta[1 * 4 + 3] += math.radians(0.05)  # joint 2's offset drifts by 0.05 deg
    shifted = TrueCell(cell.model, shifted_theta, cell.layout)
    for truth, expected in ((cell, "ok"), (shifted, "not_held")):
        r = client.post(f"{API}/robots/{rid}/checks", headers=AUTH)
        assert r.status_code == 202, r.text
        check = r.json()
        assert client.app.state.cablecal.sampler.auto == check["campaign_id"]  # type: ignore[attr-defined]
        again = client.post(f"{API}/robots/{rid}/checks", headers=AUTH)
        assert again.status_code == 409 and "running" in again.json()["detail"]
        status = client.get(f"{API}/status", headers=AUTH).json()["hold_check"]
        assert status["running"] == check["id"]
        _store_captures(
            client, check["campaign_id"], poses, noisy_lengths(truth, poses, rng, noise_mm=NOISE_MM)
        )
        done = _wait_check(client, rid, check["id"])
        assert done["status"] == expected, done
        assert done["n"] == 6 and done["rms_mm"] is not None
        assert client.app.state.cablecal.sampler.auto is None  # type: ignore[attr-defined]
        status = client.get(f"{API}/status", headers=AUTH).json()["hold_check"]
        assert status["state"] == expected and status["check_id"] == check["id"]
        assert status["rms_mm"] == pytest.approx(done["rms_mm"])
        assert _gauge(client, rid) == pytest.approx(done["rms_mm"])
        # the deprecated name (until 0.3.0) carries the same figure
        assert _gauge(client, rid, "cablecal_drift_rms_mm") == pytest.approx(done["rms_mm"])
    params = {"kind": "hold_check_not_held"}
    events = client.get(f"{API}/events", params=params, headers=AUTH).json()
    assert events and events[-1]["detail"]["check_id"] == done["id"]
    assert events[-1]["detail"]["status"] == "not_held"
    ok = client.get(f"{API}/events", params={"kind": "hold_check"}, headers=AUTH).json()
    assert ok and ok[-1]["detail"]["status"] == "ok"


def test_check_refused_while_auto_capture_runs(
    client: TestClient, calibrated: dict[str, int]
) -> None:
    sampler = client.app.state.cablecal.sampler  # type: ignore[attr-defined]
    sampler.auto = calibrated["campaign_id"]
    try:
        r = client.post(f"{API}/robots/{calibrated['robot_id']}/checks", headers=AUTH)
        assert r.status_code == 409 and "auto capture" in r.json()["detail"]
    finally:
        sampler.auto = None
    other = _uncalibrated_robot(client)
    assert client.post(f"{API}/robots/{other}/checks", headers=AUTH).status_code == 404


def test_check_times_out_and_status_reads_it_from_memory(
    tmp_path: Path, cell: TrueCell, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A check whose poses are never visited fails at its timeout. ``GET /status`` must not
    query SQLite (the store lock can be held by a capture or an import): after start-up the
    hold-check block comes from the monitor's memory, and a check it stores shows at once."""
    settings = Settings(state_dir=tmp_path, api_token=TOKEN, hold_check={"timeout_s": 1.0})
    with TestClient(create_app(settings, TOKEN, sampler_factory=FakeSampler)) as c:
        cid = _campaign(c, cell, 40, seed=3)
        store = c.app.state.cablecal.store  # type: ignore[attr-defined]
        rid = c.get(f"{API}/campaigns/{cid}", headers=AUTH).json()["robot_id"]
        job = store.create_job(cid, rid, "lm", {})
        store.save_result(job["id"], {**_fake_result(), "robot": "hsr-jr680"})
        queries: list[object] = []
        list_checks = store.list_checks
        monkeypatch.setattr(
            store, "list_checks", lambda *a, **k: queries.append(a) or list_checks(*a, **k)
        )
        for _ in range(20):
            assert c.get(f"{API}/status", headers=AUTH).json()["hold_check"]["state"] == "none"
        assert queries == []
        r = c.post(f"{API}/robots/{rid}/checks", headers=AUTH)
        assert r.status_code == 202, r.text
        assert (
            c.get(f"{API}/status", headers=AUTH).json()["hold_check"]["running"] == r.json()["id"]
        )
        done = _wait_check(c, rid, r.json()["id"])
        assert done["status"] == "failed" and "0 of 8 check poses" in done["error"]
        n_before = len(queries)  # start_check counts the robot's checks: not /status
        for _ in range(20):
            hold = c.get(f"{API}/status", headers=AUTH).json()["hold_check"]
            assert hold["state"] == "failed" and hold["check_id"] == done["id"]
            assert hold["running"] is None and hold["last_check_at"] == done["finished_at"]
        assert len(queries) == n_before


def _fake_result() -> dict[str, Any]:
    model = builtin_model("hsr-jr680")
    dh = [
        {"joint": j + 1, "alpha_deg": r[0], "a_mm": r[1], "d_mm": r[2], "theta_deg": r[3]}
        for j, r in enumerate(model.dh_table.tolist())
    ]
    return {
        "convention": "dh",
        "dh": dh,
        "tool_mm": [0.0, 0.0, 100.0],
        "anchor_id": "A",
        "anchor_mm": [1500.0, 0.0, 0.0],
        "length_offset_mm": 0.0,
        "metrics": {"after": {"test": {"n": 10, "rmse_mm": 0.05}}},
    }


def test_scheduled_check_starts_by_itself(tmp_path: Path, cell: TrueCell) -> None:
    hold = {"timeout_s": 1.0, "check_interval_h": 0.0003}  # about 1 s
    settings = Settings(state_dir=tmp_path, api_token=TOKEN, hold_check=hold)
    with TestClient(create_app(settings, TOKEN, sampler_factory=FakeSampler)) as c:
        cid = _campaign(c, cell, 20, seed=8)
        store = c.app.state.cablecal.store  # type: ignore[attr-defined]
        rid = c.get(f"{API}/campaigns/{cid}", headers=AUTH).json()["robot_id"]
        job = store.create_job(cid, rid, "lm", {})
        store.save_result(job["id"], {**_fake_result(), "robot": "hsr-jr680"})
        deadline = time.monotonic() + 20
        while not (checks := c.get(f"{API}/robots/{rid}/checks", headers=AUTH).json()):
            assert time.monotonic() < deadline, "no scheduled check"
            time.sleep(0.2)
        assert checks[0]["trigger"] == "schedule"
        assert c.get(f"{API}/status", headers=AUTH).json()["hold_check"]["check_interval_h"] > 0


def test_compensated_targets_as_robot_programs(
    client: TestClient, cell: TrueCell, calibrated: dict[str, int]
) -> None:
    from calib.programs import DOWNLOAD_FORMATS
    from calib.programs.registry import parse_program

    rid = calibrated["robot_id"]
    q = random_poses_deg(cell, 6, np.random.default_rng(4))
    body = [{f"q{j + 1}": float(v) for j, v in enumerate(row)} for row in q]
    url = f"{API}/robots/{rid}/compensate"
    corrected = np.array(
        [
            [row[f"q{j}"] for j in range(1, 7)]
            for row in client.post(url, json=body, headers=AUTH).json()["rows"]
        ]
    )
    for fmt in DOWNLOAD_FORMATS:
        r = client.post(url, json=body, headers=AUTH, params={"format": fmt, "dwell_s": 1.5})
        assert r.status_code == 200, r.text
        assert "attachment" in r.headers["content-disposition"]
        if fmt == "csv":
            assert r.text.startswith("index,q1_nominal")
            continue
        back = parse_program(fmt, r.text)
        np.testing.assert_allclose(np.array(back.joints_deg), corrected, atol=0.0005 + 1e-9)
        assert back.dwell_s == 1.5
    r = client.post(url, json=body, headers=AUTH, params={"format": "gcode"})
    assert r.status_code == 422 and "format" in _text(r)


def test_check_poses_download_as_csv_and_robot_programs(
    client: TestClient, calibrated: dict[str, int]
) -> None:
    """Issue 27 item 3: the check poses reach the robot as the plan does, from the check
    poses' own route: CSV and every program format, each pose back from the program."""
    from calib.programs import DOWNLOAD_FORMATS
    from calib.programs.registry import parse_program

    rid = calibrated["robot_id"]
    url = f"{API}/robots/{rid}/check-poses"
    poses = client.get(url, headers=AUTH).json()["poses_deg"]
    for fmt in DOWNLOAD_FORMATS:
        r = client.get(url, headers=AUTH, params={"format": fmt})
        assert r.status_code == 200, (fmt, r.text)
        assert f"robot-{rid}-check-poses" in r.headers["content-disposition"].lower().replace(
            "_", "-"
        ), r.headers["content-disposition"]
        if fmt == "csv":
            lines = r.text.splitlines()
            assert lines[0] == "pose,q1,q2,q3,q4,q5,q6" and len(lines) == 1 + len(poses)
            continue
        back = parse_program(fmt, r.text)
        assert len(back.joints_deg) == len(poses), fmt
        for got, want in zip(back.joints_deg, poses, strict=True):
            assert max(abs(a - b) for a, b in zip(got, want, strict=True)) <= 0.0005 + 1e-9
    for bad in ({"format": "gcode"}, {"format": "krl", "speed_pct": 0}):
        assert client.get(url, headers=AUTH, params=bad).status_code == 422
    r = client.get(
        f"{API}/robots/{_uncalibrated_robot(client)}/check-poses?format=rapid", headers=AUTH
    )
    assert r.status_code == 404 and "no accepted calibration" in r.json()["detail"], r.text
