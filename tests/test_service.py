"""The REST service in-process (TestClient runs the lifespan): routes, auth, bad input, jobs.

The sampler is replaced by a scripted fake (the real one is tested in test_sampler.py and end
to end in test_e2e.py); the store, the job pool and identification are real.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient
from prometheus_client.parser import text_string_to_metric_families

from calib.dataset import samples_to_csv
from calib.models import builtin_model
from daemon.api.deps import AppState
from daemon.api.main import create_app
from daemon.config import Settings
from daemon.datafiles import read_samples
from daemon.sampler.capture import Capture, CaptureRejected
from daemon.store import JOB_FINISHED, Store

TOKEN = "test-token-0123456789"
AUTH = {"Authorization": f"Bearer {TOKEN}"}


class FakeSampler:
    """Stands in for daemon.sampler.Sampler: captures come from a script."""

    def __init__(self, state: AppState) -> None:
        self.state = state
        self.next_joints: list[float] = [0.0, -60.0, 200.0, -170.0, 40.0, 60.0]
        self.reject: CaptureRejected | None = None
        self.auto: int | None = None
        self.started = False

    async def start(self) -> None:
        self.started = True

    async def stop(self) -> None:
        self.started = False

    async def capture(
        self, campaign_id: int, anchor: str = "A", joints_deg: list[float] | None = None
    ) -> dict[str, Any]:
        if self.reject is not None:
            raise self.reject
        q = joints_deg or self.next_joints
        now = time.time()
        cap = Capture(
            joints_deg=(q[0], q[1], q[2], q[3], q[4], q[5]),
            joints_std_deg=(0.0,) * 6,  # type: ignore[arg-type]
            length_mm=500.0,
            length_std_mm=0.01,
            count=10,
            anchor=anchor,
            t_start_wall=now - 0.5,
            t_end_wall=now,
            mode="manual",
        )
        return self.state.store.store_capture(campaign_id, cap)

    def set_auto(
        self, campaign_id: int | None, anchor: str = "A", known_poses_deg: Any = None
    ) -> None:
        self.auto = campaign_id

    @property
    def auto_campaign_id(self) -> int | None:
        return self.auto

    def status(self) -> dict[str, Any]:
        return {
            "devices": {"indicator": {"name": "indicator", "role": "indicator", "state": "ok"}},
            "sampler": {"mode": "auto" if self.auto else "manual", "auto_campaign_id": self.auto},
        }

    def update_age_metrics(self) -> None:
        pass

    def recent_readings(self, since_wall_s: float, limit: int) -> list[Any]:
        return []


def _settings(tmp: Path, **kw: Any) -> Settings:
    return Settings(state_dir=tmp, api_token=TOKEN, **kw)


@pytest.fixture(scope="module")
def client(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TestClient]:
    tmp = tmp_path_factory.mktemp("svc")
    app = create_app(_settings(tmp), TOKEN, sampler_factory=FakeSampler)
    with TestClient(app) as c:
        yield c


def _sampler(client: TestClient) -> FakeSampler:
    sampler: FakeSampler = client.app.state.cablecal.sampler  # type: ignore[attr-defined]
    return sampler


def _campaign(client: TestClient, name: str = "c") -> int:
    r = client.post(
        "/api/v1/campaigns", json={"name": name, "robot_model": "hsr-jr680"}, headers=AUTH
    )
    assert r.status_code == 201, r.text
    return int(r.json()["id"])


def _wait_job(client: TestClient, job_id: int, timeout_s: float = 90) -> dict[str, Any]:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        job = client.get(f"/api/v1/identifications/{job_id}", headers=AUTH).json()
        if job["status"] in JOB_FINISHED:
            return dict(job)
        time.sleep(0.2)
    raise AssertionError(f"job {job_id} did not finish: {job}")


# ------------------------------------------------------------------------- auth
def test_every_write_route_requires_the_token(client: TestClient) -> None:
    spec = client.get("/openapi.json").json()
    writes = [
        (m.upper(), path)
        for path, ops in spec["paths"].items()
        for m in ops
        if m in ("post", "put", "patch", "delete")
    ]
    writes.append(("POST", "/api/v1/debug/hang"))  # hidden from the schema
    assert len(writes) >= 9
    for method, path in writes:
        url = path.replace("{campaign_id}", "1").replace("{sample_id}", "1")
        url = url.replace("{job_id}", "1")
        for headers in ({}, {"Authorization": "Bearer wrong"}):
            r = client.request(method, url, json={}, headers=headers)
            assert r.status_code == 401, (method, url, r.status_code, r.text)
            assert r.headers["www-authenticate"] == "Bearer"


def test_reads_need_the_token_unless_public(client: TestClient, tmp_path: Path) -> None:
    assert client.get("/api/v1/health").status_code == 200
    assert client.get("/api/v1/status").status_code == 401
    assert client.get("/api/v1/campaigns").status_code == 401
    assert client.get("/api/v1/status", headers=AUTH).status_code == 200
    app = create_app(_settings(tmp_path, public_reads=True), TOKEN, sampler_factory=FakeSampler)
    with TestClient(app) as open_client:
        assert open_client.get("/api/v1/campaigns").status_code == 200
        assert open_client.post("/api/v1/campaigns", json={"name": "x"}).status_code == 401


def test_non_loopback_bind_without_token_is_refused() -> None:
    from daemon.config import ConfigError

    with pytest.raises(ConfigError, match="api_token"):
        Settings(host="0.0.0.0").resolve_token()
    token, generated = Settings(host="127.0.0.1").resolve_token()
    assert generated and len(token) >= 24
    assert Settings(host="0.0.0.0", api_token="x" * 20).resolve_token() == ("x" * 20, False)


# ------------------------------------------------------------------------- campaigns
def test_campaign_create_list_get(client: TestClient) -> None:
    cid = _campaign(client, "line 3 robot 2")
    got = client.get(f"/api/v1/campaigns/{cid}", headers=AUTH).json()
    assert got["name"] == "line 3 robot 2"
    assert any(c["id"] == cid for c in client.get("/api/v1/campaigns", headers=AUTH).json())
    assert client.get("/api/v1/campaigns/999999", headers=AUTH).status_code == 404


def test_campaign_with_uploaded_model_and_bad_models(client: TestClient) -> None:
    from calib.models import builtin_model

    model = builtin_model("hsr-jr680").to_dict()
    model["name"] = "my-robot"
    r = client.post("/api/v1/campaigns", json={"name": "u", "robot_model": model}, headers=AUTH)
    assert r.status_code == 201, r.text
    robot = client.get(f"/api/v1/robots/{r.json()['robot_id']}", headers=AUTH).json()
    assert robot["name"] == "my-robot"
    r = client.post("/api/v1/campaigns", json={"name": "u", "robot_model": "nope"}, headers=AUTH)
    assert r.status_code == 422 and "robot_model" in r.text
    model["joints"][2]["a_mm"] = "abc"
    r = client.post("/api/v1/campaigns", json={"name": "u", "robot_model": model}, headers=AUTH)
    assert r.status_code == 422 and "a_mm" in r.text, r.text
    r = client.post("/api/v1/campaigns", json={"robot_model": "hsr-jr680"}, headers=AUTH)
    assert r.status_code == 422 and "name" in r.text


# ------------------------------------------------------------------------- captures
def test_manual_capture_and_rejections(client: TestClient) -> None:
    cid = _campaign(client)
    r = client.post(f"/api/v1/campaigns/{cid}/captures", json={}, headers=AUTH)
    assert r.status_code == 201, r.text
    assert r.json()["length_mm"] == 500.0
    fake = _sampler(client)
    fake.reject = CaptureRejected("moving", "robot did not settle within 10 s")
    r = client.post(f"/api/v1/campaigns/{cid}/captures", json={}, headers=AUTH)
    assert r.status_code == 409 and r.json()["detail"]["reason"] == "moving"
    fake.reject = CaptureRejected(
        "indicator_error", "IndicatorNoReply: no reply in 0.5 s", device="indicator"
    )
    r = client.post(f"/api/v1/campaigns/{cid}/captures", json={}, headers=AUTH)
    assert r.status_code == 503
    assert r.json()["detail"]["device"] == "indicator"
    assert "IndicatorNoReply" in r.json()["detail"]["detail"]
    fake.reject = None
    samples = client.get(f"/api/v1/campaigns/{cid}/samples", headers=AUTH).json()
    assert len(samples) == 1


def test_capture_joint_angles_are_validated(client: TestClient) -> None:
    cid = _campaign(client)
    bad = [0.0, 500.0, 200.0, 0.0, 0.0, 0.0]
    r = client.post(f"/api/v1/campaigns/{cid}/captures", json={"joints_deg": bad}, headers=AUTH)
    assert r.status_code == 409 and "joints_deg[1]" in r.text, r.text  # the robot's limits
    r = client.post(f"/api/v1/campaigns/{cid}/captures", json={"joints_deg": [1, 2]}, headers=AUTH)
    assert r.status_code == 422 and "joints_deg" in r.text
    r = client.post(f"/api/v1/campaigns/{cid}/captures", json={"joints_deg": "abc"}, headers=AUTH)
    assert r.status_code == 422 and "joints_deg" in r.text
    assert client.get(f"/api/v1/campaigns/{cid}/samples", headers=AUTH).json() == []


def test_auto_capture_switch(client: TestClient) -> None:
    a, b = _campaign(client, "a"), _campaign(client, "b")
    r = client.put(f"/api/v1/campaigns/{a}/auto-capture", json={"enabled": True}, headers=AUTH)
    assert r.status_code == 200 and r.json()["auto_capture"] is True
    assert _sampler(client).auto == a
    client.put(f"/api/v1/campaigns/{b}/auto-capture", json={"enabled": True}, headers=AUTH)
    assert _sampler(client).auto == b
    assert client.get(f"/api/v1/campaigns/{a}", headers=AUTH).json()["auto_capture"] is False
    client.put(f"/api/v1/campaigns/{b}/auto-capture", json={"enabled": False}, headers=AUTH)
    assert _sampler(client).auto is None
    r = client.put(f"/api/v1/campaigns/{a}/auto-capture", json={"enabled": "yes?"}, headers=AUTH)
    assert r.status_code == 422 and "enabled" in r.text


# ------------------------------------------------------------------------- samples
def _real_csv(rows: int) -> str:
    s = read_samples(None)
    return samples_to_csv(s.subset(np.arange(rows)))


def test_csv_import_export_and_bad_rows(client: TestClient) -> None:
    cid = _campaign(client)
    url = f"/api/v1/campaigns/{cid}/samples/import"
    hdr = {**AUTH, "Content-Type": "text/csv"}
    good = _real_csv(40)
    lines = good.splitlines()
    # Line 37 of the file (header = 1) gets a length beyond the sensor's 2000 mm.
    cells = lines[36].split(",")
    cells[6] = "2500.0"
    bad = "\n".join([*lines[:36], ",".join(cells), *lines[37:]]) + "\n"
    r = client.post(url, content=bad, headers=hdr)
    assert r.status_code == 400, r.text
    assert r.json()["detail"]["row"] == 37 and r.json()["detail"]["column"] in ("L", "l")
    assert client.get(f"/api/v1/campaigns/{cid}/samples", headers=AUTH).json() == []
    nan = good.replace(lines[5], lines[5].replace(lines[5].split(",")[2], "nan", 1))
    r = client.post(url, content=nan, headers=hdr)
    assert r.status_code == 400 and r.json()["detail"]["row"] == 6, r.text
    r = client.post(url, content="q1,q2,q3\n1,2,3\n", headers=hdr)
    assert r.status_code == 400 and "q4" in r.text
    r = client.post(url, content=good, headers=hdr)
    assert r.status_code == 201 and r.json()["imported"] == 40
    csv_text = client.get(f"/api/v1/campaigns/{cid}/samples?format=csv", headers=AUTH).text
    from calib.dataset import parse_samples_csv

    back = parse_samples_csv(csv_text)
    orig = parse_samples_csv(good)
    assert len(back) == 40
    assert abs(back.length_mm - orig.length_mm).max() < 1e-6
    r = client.get(f"/api/v1/campaigns/{cid}/samples?format=xml", headers=AUTH)
    assert r.status_code == 422 and "format" in r.text


def test_exclude_and_include_a_sample(client: TestClient) -> None:
    cid = _campaign(client)
    client.post(
        f"/api/v1/campaigns/{cid}/samples/import",
        content=_real_csv(3),
        headers={**AUTH, "Content-Type": "text/csv"},
    )
    sid = client.get(f"/api/v1/campaigns/{cid}/samples", headers=AUTH).json()[1]["id"]
    r = client.patch(
        f"/api/v1/samples/{sid}", json={"excluded": True, "reason": "bumped"}, headers=AUTH
    )
    assert r.status_code == 200 and r.json()["excluded"] is True
    csv_rows = client.get(f"/api/v1/campaigns/{cid}/samples?format=csv", headers=AUTH).text
    assert len(csv_rows.strip().splitlines()) == 1 + 2
    r = client.patch(f"/api/v1/samples/{sid}", json={"excluded": False}, headers=AUTH)
    assert r.json()["excluded"] is False
    assert (
        client.patch("/api/v1/samples/9999999", json={"excluded": True}, headers=AUTH).status_code
        == 404
    )


# ------------------------------------------------------------------------- identification
def test_identification_job_result_and_calibrated_model(client: TestClient) -> None:
    cid = _campaign(client)
    client.post(
        f"/api/v1/campaigns/{cid}/samples/import",
        content=_real_csv(120),
        headers={**AUTH, "Content-Type": "text/csv"},
    )
    robot_id = client.get(f"/api/v1/campaigns/{cid}", headers=AUTH).json()["robot_id"]
    r = client.post(
        f"/api/v1/campaigns/{cid}/identifications",
        json={"method": "lm", "test_fraction": 0.2, "seed": 1},
        headers=AUTH,
    )
    assert r.status_code == 202, r.text
    job = _wait_job(client, r.json()["id"])
    assert job["status"] == "succeeded", job
    assert job["progress"]["fraction"] == 1.0
    result = job["result"]
    for key in ("robot", "method", "dh", "dh_error", "tool_mm", "anchor_mm", "metrics"):
        assert key in result
    after = result["metrics"]["after"]["test"]["rmse_mm"]
    before = result["metrics"]["before"]["test"]["rmse_mm"]
    assert math.isfinite(after) and after < before
    # The real data give implausible parameters (README): not accepted automatically.
    if not result["plausibility"]["plausible"]:
        assert job["accepted"] is False
        assert (
            client.get(f"/api/v1/robots/{robot_id}/calibrated-model", headers=AUTH).status_code
            == 404
        )
        r = client.post(f"/api/v1/identifications/{job['id']}/accept", headers=AUTH)
        assert r.status_code == 200 and r.json()["accepted"] is True
    model = client.get(f"/api/v1/robots/{robot_id}/calibrated-model", headers=AUTH).json()
    assert model["job_id"] == job["id"] and len(model["dh"]) == 6


@pytest.mark.slow
def test_one_current_calibration_until_accept_and_numeric_progress(client: TestClient) -> None:
    """Operator facts: a robot has exactly one current calibration; a second result waits for
    Accept (compared on the same held-out rows); de and ukf-vslm report numeric progress."""
    cid = _campaign(client, "current")
    client.post(
        f"/api/v1/campaigns/{cid}/samples/import",
        content=_real_csv(100),
        headers={**AUTH, "Content-Type": "text/csv"},
    )
    robot_id = client.get(f"/api/v1/campaigns/{cid}", headers=AUTH).json()["robot_id"]
    url = f"/api/v1/campaigns/{cid}/identifications"

    def run(method: str, robust: str = "auto") -> dict[str, Any]:
        body = {"method": method, "seed": 2, "robust": robust}
        r = client.post(url, json=body, headers=AUTH)
        assert r.status_code == 202, r.text
        job = _wait_job(client, r.json()["id"])
        assert job["status"] == "succeeded", job
        progress = job["progress"]
        assert isinstance(progress["cost_rms_mm"], float) and progress["cost_rms_mm"] > 0
        assert isinstance(progress["iteration"], int) and progress["iteration"] >= 1
        return job

    first = run("ukf-vslm")
    client.post(f"/api/v1/identifications/{first['id']}/accept", headers=AUTH)
    # de: numeric progress while it runs, then the operator cancels it.
    r = client.post(url, json={"method": "de", "robust": "none"}, headers=AUTH)
    de_id = r.json()["id"]
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        de = client.get(f"/api/v1/identifications/{de_id}", headers=AUTH).json()
        if de["progress"]["cost_rms_mm"] is not None or de["status"] in JOB_FINISHED:
            break
        time.sleep(0.2)
    assert isinstance(de["progress"]["cost_rms_mm"], float), de
    assert isinstance(de["progress"]["iteration"], int), de
    client.delete(f"/api/v1/identifications/{de_id}", headers=AUTH)
    assert _wait_job(client, de_id)["status"] in ("cancelled", "succeeded")
    second = run("lm")
    assert second["current"] is False and "waiting for Accept" in second["message"]
    listed = client.get(url, headers=AUTH).json()
    assert [j["id"] for j in listed if j["current"]] == [first["id"]]
    robot = client.get(f"/api/v1/robots/{robot_id}", headers=AUTH).json()
    assert robot["current_identification_id"] == first["id"]
    cmp = client.get(f"/api/v1/identifications/{second['id']}/compare", headers=AUTH).json()
    assert cmp["n_rows"] == second["result"]["split"]["n_test"] == 20
    assert cmp["current"]["job_id"] == first["id"] and cmp["new"]["job_id"] == second["id"]
    assert cmp["new"]["test_rmse_mm"] == pytest.approx(
        second["result"]["metrics"]["after"]["test"]["rmse_mm"], rel=1e-6
    )
    assert cmp["changed"] and all(abs(c["change"]) > 1e-3 for c in cmp["changed"])
    r = client.post(f"/api/v1/identifications/{second['id']}/accept", headers=AUTH)
    assert r.status_code == 200 and r.json()["current"] is True
    assert r.json()["message"] == f"accepted: the current calibration (replaces job {first['id']})"
    listed = client.get(url, headers=AUTH).json()
    assert [j["id"] for j in listed if j["current"]] == [second["id"]]
    spec = client.get("/api/v1/options/identify", headers=AUTH).json()
    names = [f["name"] for f in spec["fields"]]
    assert names[:2] == ["method", "test_fraction"] and "fix" in names and "fixed" not in names
    assert "de" in spec["fields"][0]["choices"] and "succeeded" in spec["finished_states"]


def test_identification_readiness_applies_the_rule_for_the_page(client: TestClient) -> None:
    cid = _campaign(client, "ready")
    client.post(
        f"/api/v1/campaigns/{cid}/samples/import",
        content=_real_csv(40),
        headers={**AUTH, "Content-Type": "text/csv"},
    )
    url = f"/api/v1/campaigns/{cid}/identification-readiness"
    r = client.get(url, headers=AUTH).json()
    camp = client.get(f"/api/v1/campaigns/{cid}", headers=AUTH).json()
    assert (r["n_train"], r["n_test"], r["ready"]) == (32, 8, True)
    assert r["min_samples"] == camp["min_samples_to_identify"]
    r = client.get(url, params={"test_fraction": 0.5}, headers=AUTH).json()
    assert (r["n_train"], r["ready"]) == (20, False) and r["min_samples"] > 40
    r = client.get(url, params={"test_fraction": 0.9999999}, headers=AUTH).json()
    assert r["min_samples"] is None and r["ready"] is False  # answered at once, not searched
    assert client.get(url, params={"test_fraction": "abc"}, headers=AUTH).status_code == 422
    assert client.get(url, params={"test_fraction": 1.0}, headers=AUTH).status_code == 422


def test_identification_bad_options(client: TestClient) -> None:
    cid = _campaign(client)
    url = f"/api/v1/campaigns/{cid}/identifications"
    r = client.post(url, json={"method": "magic"}, headers=AUTH)
    assert r.status_code == 422 and "method" in r.text
    r = client.post(url, json={"test_fraction": 1.5}, headers=AUTH)
    assert r.status_code == 422 and "test_fraction" in r.text
    r = client.post(url, json={}, headers=AUTH)  # no samples yet: the campaign's state, 409
    assert r.status_code == 409 and "samples" in r.text
    client.post(
        f"/api/v1/campaigns/{cid}/samples/import",
        content=_real_csv(60),
        headers={**AUTH, "Content-Type": "text/csv"},
    )
    r = client.post(url, json={"fixed": ["d9"]}, headers=AUTH)
    assert r.status_code == 409 and "d9" in r.text  # a name the robot model lacks
    assert (
        client.post("/api/v1/campaigns/99999/identifications", json={}, headers=AUTH).status_code
        == 404
    )


def test_too_few_training_rows_is_409_naming_the_count(client: TestClient) -> None:
    """The job submission runs calib.options.validate with the campaign's robot: 30 real rows
    leave 24 for training at the default 20 % test set, one short of the 24 parameters + 1."""
    cid = _campaign(client)
    client.post(
        f"/api/v1/campaigns/{cid}/samples/import",
        content=_real_csv(30),
        headers={**AUTH, "Content-Type": "text/csv"},
    )
    url = f"/api/v1/campaigns/{cid}/identifications"
    r = client.post(url, json={}, headers=AUTH)
    assert r.status_code == 409, r.text
    assert "24 training samples" in r.text and "need at least 25" in r.text, r.text
    assert "solves 24 parameters" in r.text, r.text
    r = client.post(url, json={"test_fraction": 0.0}, headers=AUTH)  # 30 rows train: accepted
    assert r.status_code == 202, r.text
    client.delete(f"/api/v1/identifications/{r.json()['id']}", headers=AUTH)
    assert _wait_job(client, r.json()["id"])["status"] in ("cancelled", "succeeded")


def test_cancel_a_running_job(client: TestClient) -> None:
    cid = _campaign(client)
    client.post(
        f"/api/v1/campaigns/{cid}/samples/import",
        content=_real_csv(120),
        headers={**AUTH, "Content-Type": "text/csv"},
    )
    r = client.post(f"/api/v1/campaigns/{cid}/identifications", json={"method": "de"}, headers=AUTH)
    job_id = r.json()["id"]
    deadline = time.monotonic() + 30
    while (
        client.get(f"/api/v1/identifications/{job_id}", headers=AUTH).json()["status"] == "queued"
    ):
        assert time.monotonic() < deadline
        time.sleep(0.1)
    r = client.delete(f"/api/v1/identifications/{job_id}", headers=AUTH)
    assert r.status_code == 200
    job = _wait_job(client, job_id, timeout_s=60)
    assert job["status"] == "cancelled", job
    assert client.delete("/api/v1/identifications/999999", headers=AUTH).status_code == 404


def test_running_job_is_marked_interrupted_after_restart(tmp_path: Path) -> None:
    store = Store(Store.default_path(tmp_path))
    robot = store.ensure_builtin_robot("hsr-jr680")
    camp = store.create_campaign("c", int(robot["id"]), "")
    job = store.create_job(int(camp["id"]), int(robot["id"]), "lm", {})
    store.update_job(int(job["id"]), status="running", progress=0.4)
    store.close()
    app = create_app(_settings(tmp_path), TOKEN, sampler_factory=FakeSampler)
    with TestClient(app) as c:
        got = c.get(f"/api/v1/identifications/{job['id']}", headers=AUTH).json()
    assert got["status"] == "failed" and got["interrupted"] is True


# ------------------------------------------------------------------------- metrics, docs, page
def test_metrics_parse_and_count_requests(client: TestClient) -> None:
    client.get("/api/v1/status", headers=AUTH)
    text = client.get("/metrics").text
    families = {f.name: f for f in text_string_to_metric_families(text)}
    lat = families["cablecal_http_request_duration_seconds"]
    routes = {s.labels.get("route") for s in lat.samples}
    assert "/api/v1/status" in routes
    assert "cablecal_captures" in families


def test_openapi_documents_every_route(client: TestClient) -> None:
    spec = client.get("/openapi.json").json()
    paths = spec["paths"]
    for p in (
        "/api/v1/health",
        "/api/v1/status",
        "/api/v1/campaigns",
        "/api/v1/campaigns/{campaign_id}",
        "/api/v1/campaigns/{campaign_id}/captures",
        "/api/v1/campaigns/{campaign_id}/auto-capture",
        "/api/v1/campaigns/{campaign_id}/samples",
        "/api/v1/campaigns/{campaign_id}/samples/import",
        "/api/v1/samples/{sample_id}",
        "/api/v1/campaigns/{campaign_id}/identifications",
        "/api/v1/identifications/{job_id}",
        "/api/v1/robots/{robot_id}/calibrated-model",
    ):
        assert p in paths, p
        for op in paths[p].values():
            assert op.get("summary"), (p, op)
    assert client.get("/docs").status_code == 200
    assert "cablecal" in client.get("/").text


def test_not_found_is_one_404_path_naming_the_resource(client: TestClient) -> None:
    """Every missing row comes from the store's StoreNotFound through one handler, with the
    REST name of the resource (a job is an identification)."""
    model = builtin_model("hsr-jr680").to_dict()
    body = {"name": "nf", "robot": "nf arm", "robot_model": model}
    r = client.post("/api/v1/campaigns", json=body, headers=AUTH)
    rid = r.json()["robot_id"]  # a new robot: no calibration accepted yet
    cases = [
        ("GET", "/api/v1/campaigns/999999", None, "campaign 999999: not found"),
        ("GET", "/api/v1/campaigns/999999/samples", None, "campaign 999999: not found"),
        ("PATCH", "/api/v1/samples/999999", {"excluded": True}, "sample 999999: not found"),
        ("GET", "/api/v1/identifications/999999", None, "identification 999999: not found"),
        ("DELETE", "/api/v1/identifications/999999", None, "identification 999999: not found"),
        ("POST", "/api/v1/campaigns/999999/identifications", {}, "campaign 999999: not found"),
        ("GET", "/api/v1/robots/999999", None, "robot 999999: not found"),
        (
            "GET",
            f"/api/v1/robots/{rid}/calibrated-model",
            None,
            f"robot {rid}: no accepted calibration yet",
        ),
    ]
    for method, url, body, detail in cases:
        r = client.request(method, url, json=body, headers=AUTH)
        assert (r.status_code, r.json()) == (404, {"detail": detail}), (method, url)


def test_store_backed_routes_declare_their_response_models(client: TestClient) -> None:
    spec = client.get("/openapi.json").json()
    schemas = spec["components"]["schemas"]

    def model_of(path: str, method: str, status: str = "200") -> dict[str, Any]:
        schema = spec["paths"][path][method]["responses"][status]["content"]["application/json"]
        body = schema["schema"].get("items", schema["schema"])
        ref = body["$ref"] if "$ref" in body else body["anyOf"][0]["$ref"]  # the first of
        return dict(schemas[ref.rsplit("/", 1)[1]])  # a union (calibrated-model: or a file)

    assert "n_included" in model_of("/api/v1/campaigns", "get")["required"]
    assert "n_included" in model_of("/api/v1/campaigns/{campaign_id}", "get")["required"]
    sample = model_of("/api/v1/campaigns/{campaign_id}/samples", "get")
    assert {"q1", "length_std_mm", "pose_group"} <= set(sample["required"])
    assert "pose_group" in model_of("/api/v1/samples/{sample_id}", "patch")["required"]
    job = model_of("/api/v1/identifications/{job_id}", "get")
    assert {"status", "progress", "result", "accepted"} <= set(job["required"])
    assert "tool_mm" in model_of("/api/v1/robots/{robot_id}/calibrated-model", "get")["required"]
    assert "detail" in model_of("/api/v1/events", "get")["required"]
