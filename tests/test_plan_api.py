"""POST/GET /campaigns/{id}/plan: planning off the event loop, progress from the samples."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from typing import Any

import pytest
from fastapi.testclient import TestClient
from test_service import AUTH, TOKEN, FakeSampler, _settings

from daemon.api.main import create_app
from daemon.datafiles import bundled_dataset_text
from daemon.sampler.capture import Capture

ANCHOR = [1430.0, 330.0, 230.0]
SMALL = {"anchors_mm": [ANCHOR], "n": 8, "candidates": 200, "seed": 2}


@pytest.fixture(scope="module")
def client(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TestClient]:
    app = create_app(_settings(tmp_path_factory.mktemp("plan")), TOKEN, sampler_factory=FakeSampler)
    with TestClient(app) as c:
        yield c


def _campaign(client: TestClient) -> int:
    r = client.post(
        "/api/v1/campaigns", json={"name": "p", "robot_model": "hsr-jr680"}, headers=AUTH
    )
    assert r.status_code == 201, r.text
    return int(r.json()["id"])


def _plan(client: TestClient, cid: int, tol_deg: float | None = None) -> dict[str, Any]:
    params = {} if tol_deg is None else {"tol_deg": tol_deg}
    r = client.get(f"/api/v1/campaigns/{cid}/plan", headers=AUTH, params=params)
    assert r.status_code == 200, r.text
    return dict(r.json())


def _q(pose: dict[str, Any], shift_deg: float = 0.0) -> list[float]:
    return [float(pose[f"q{j}"]) + shift_deg for j in range(1, 7)]


def test_plan_then_progress_through_captures_imports_and_exclusion(client: TestClient) -> None:
    cid = _campaign(client)
    assert client.get(f"/api/v1/campaigns/{cid}", headers=AUTH).json()["plan_id"] is None
    r = client.post(f"/api/v1/campaigns/{cid}/plan", json=SMALL, headers=AUTH)
    assert r.status_code == 201, r.text
    made = r.json()
    # The campaign names its current plan (the page asks for a plan only then: no 404).
    listed = {c["id"]: c for c in client.get("/api/v1/campaigns", headers=AUTH).json()}
    assert listed[cid]["plan_id"] == made["id"]
    again = client.post(f"/api/v1/campaigns/{cid}/plan", json=SMALL, headers=AUTH).json()
    assert client.get(f"/api/v1/campaigns/{cid}", headers=AUTH).json()["plan_id"] == again["id"]
    assert again["id"] > made["id"]
    assert len(made["poses"]) == 8 and made["options"]["n"] == 8
    assert made["summary"]["tcp_sigma_mm"]["plan"]["rms"] > 0
    assert made["progress"] == {
        "n_planned": 8,
        "n_done": 0,
        "n_pending": 8,
        "n_not_capturable": 0,
        "fraction_done": 0.0,
        "tol_deg": 0.5,
        "next_pose": 1,
    }
    poses = _plan(client, cid)["poses"]
    assert poses == made["poses"]
    assert all(p["status"] == "pending" and p["sample_id"] is None for p in poses)

    # A manual capture 0.2 deg off pose 1 measures it; with a 0.1 deg tolerance it does not.
    r = client.post(
        f"/api/v1/campaigns/{cid}/captures", json={"joints_deg": _q(poses[0], 0.2)}, headers=AUTH
    )
    assert r.status_code == 201, r.text
    sid = r.json()["id"]
    got = _plan(client, cid)
    assert got["poses"][0]["status"] == "done" and got["poses"][0]["sample_id"] == sid
    assert got["progress"]["n_done"] == 1 and got["progress"]["next_pose"] == 2
    assert _plan(client, cid, tol_deg=0.1)["progress"]["n_done"] == 0

    # The same pose at another anchor is another measurement: pose 2 stays pending.
    r = client.post(
        f"/api/v1/campaigns/{cid}/captures",
        json={"joints_deg": _q(poses[1]), "anchor": "B"},
        headers=AUTH,
    )
    assert r.status_code == 201, r.text
    # A CSV import of poses 3 and 4 counts too.
    csv = "q1,q2,q3,q4,q5,q6,L\n" + "".join(
        ",".join(f"{v:.4f}" for v in _q(p)) + ",900.0\n" for p in poses[2:4]
    )
    r = client.post(
        f"/api/v1/campaigns/{cid}/samples/import",
        content=csv,
        headers={**AUTH, "Content-Type": "text/csv"},
    )
    assert r.status_code == 201, r.text
    got = _plan(client, cid)
    assert [p["status"] for p in got["poses"][:4]] == ["done", "pending", "done", "done"]
    assert got["progress"]["n_done"] == 3 and got["progress"]["n_pending"] == 5

    # Auto capture: the sampler hands its capture to the store (its sink), as here.
    store = client.app.state.cablecal.store  # type: ignore[attr-defined]
    q5 = _q(poses[4], -0.3)
    store.store_capture(
        cid,
        Capture(
            joints_deg=(q5[0], q5[1], q5[2], q5[3], q5[4], q5[5]),
            joints_std_deg=(0.001,) * 6,  # type: ignore[arg-type]
            length_mm=900.0,
            length_std_mm=0.01,
            count=10,
            anchor="A",
            t_start_wall=time.time() - 1,
            t_end_wall=time.time(),
            mode="auto",
        ),
    )
    got = _plan(client, cid)
    assert got["poses"][4]["status"] == "done" and got["progress"]["n_done"] == 4

    # Excluding the captured sample makes pose 1 pending again.
    r = client.patch(f"/api/v1/samples/{sid}", json={"excluded": True}, headers=AUTH)
    assert r.status_code == 200, r.text
    got = _plan(client, cid)
    assert got["poses"][0]["status"] == "pending" and got["progress"]["next_pose"] == 1


def test_plan_from_the_campaigns_samples(client: TestClient) -> None:
    cid = _campaign(client)
    text = bundled_dataset_text()
    r = client.post(
        f"/api/v1/campaigns/{cid}/samples/import",
        content="\n".join(text.splitlines()[:61]) + "\n",
        headers={**AUTH, "Content-Type": "text/csv"},
    )
    assert r.status_code == 201, r.text
    body = {"n": 6, "candidates": 200, "start_from_samples": True}
    r = client.post(f"/api/v1/campaigns/{cid}/plan", json=body, headers=AUTH)
    assert r.status_code == 201, r.text
    summary = r.json()["summary"]
    # The 60 measured rows alone are ill-conditioned; six planned poses help a lot.
    assert summary["condition_number_start"] > 10 * summary["condition_number"]
    assert summary["notes"] and "60 start samples" in summary["notes"][0]
    assert {p["anchor"] for p in r.json()["poses"]} == {"A"}


def test_not_found_auth_and_bounds(client: TestClient) -> None:
    cid = _campaign(client)
    r = client.get(f"/api/v1/campaigns/{cid}/plan", headers=AUTH)
    assert (r.status_code, r.json()) == (404, {"detail": f"campaign {cid}: no plan yet"})
    for method in ("GET", "POST"):
        r = client.request(method, "/api/v1/campaigns/999999/plan", json=SMALL, headers=AUTH)
        assert (r.status_code, r.json()) == (404, {"detail": "campaign 999999: not found"})
        for headers in ({}, {"Authorization": "Bearer wrong"}):
            r = client.request(method, f"/api/v1/campaigns/{cid}/plan", json=SMALL, headers=headers)
            assert r.status_code == 401, (method, r.text)
    bad = [
        ({"n": 201}, "n"),
        ({"candidates": 10_001}, "candidates"),
        ({"anchors_mm": [[1.0, 2.0]]}, "anchors_mm"),
        ({"anchors_mm": [ANCHOR] * 5}, "anchors_mm"),
        ({"joint_speed_deg_s": [30.0] * 5}, "joint_speed_deg_s"),
        ({"extension_mm": [-1.0, 100.0]}, "extension_mm"),
        ({"dwell_s": -1}, "dwell_s"),
        ({"noise_mm": 0}, "noise_mm"),
        ({"colour": "red"}, "colour"),
    ]
    for change, field in bad:
        r = client.post(f"/api/v1/campaigns/{cid}/plan", json={**SMALL, **change}, headers=AUTH)
        assert r.status_code == 422, (change, r.text)
        assert field in {str(part) for e in r.json()["detail"] for part in e["loc"]}, r.text
    # The engine's own checks are 422 naming the option too.
    engine = [
        ({"n": 50, "candidates": 20}, "candidates:"),
        ({"anchors_mm": [[9000.0, 0.0, 0.0]]}, "anchor 1 at"),
        ({"extension_mm": [900.0, 100.0]}, "extension_mm:"),
        ({"anchors_mm": None}, "anchors_mm: required"),
    ]
    for change, text in engine:
        r = client.post(f"/api/v1/campaigns/{cid}/plan", json={**SMALL, **change}, headers=AUTH)
        assert r.status_code == 422, (change, r.text)
        assert any(text in e["msg"] for e in r.json()["detail"]), (change, r.text)
    # The campaign's samples refuse (none to start from): its state, a 409 (issue 21).
    change = {"anchors_mm": None, "start_from_samples": True}
    r = client.post(f"/api/v1/campaigns/{cid}/plan", json={**SMALL, **change}, headers=AUTH)
    assert r.status_code == 409 and r.json()["detail"].startswith("start_from_samples:"), r.text
    spec = client.get("/openapi.json").json()["paths"]["/api/v1/campaigns/{campaign_id}/plan"]
    assert spec["post"]["summary"] and spec["get"]["summary"]
    r = client.get(f"/api/v1/campaigns/{cid}/plan", params={"tol_deg": 0}, headers=AUTH)
    assert r.status_code == 422
    assert client.get(f"/api/v1/campaigns/{cid}/plan", headers=AUTH).status_code == 404


def test_planning_runs_off_the_event_loop(client: TestClient) -> None:
    cid = _campaign(client)
    result: dict[str, Any] = {}
    body = {**SMALL, "n": 30, "candidates": 3000}

    def post() -> None:
        result["r"] = client.post(f"/api/v1/campaigns/{cid}/plan", json=body, headers=AUTH)

    worker = threading.Thread(target=post)
    worker.start()
    state = client.app.state  # type: ignore[attr-defined]
    deadline = time.monotonic() + 30
    while getattr(state, "planning_campaign", None) is None and time.monotonic() < deadline:
        time.sleep(0.01)
    assert state.planning_campaign == cid
    t0 = time.perf_counter()
    assert client.get("/api/v1/health").status_code == 200
    health_s = time.perf_counter() - t0
    second = client.post(f"/api/v1/campaigns/{cid}/plan", json=SMALL, headers=AUTH)
    still_planning = getattr(state, "planning_campaign", None) == cid
    worker.join(timeout=120)
    assert result["r"].status_code == 201, result["r"].text
    if still_planning:  # the plan outlasted both requests (it takes seconds): they were served
        assert second.status_code == 409 and "another plan" in second.json()["detail"]
        assert health_s < 1.0, health_s


BIG = 2**63  # one past SQLite's largest INTEGER


def test_ids_beyond_sqlite_integer_blank_and_oversized_strings_are_422(
    client: TestClient,
) -> None:
    for method in ("GET", "POST"):
        r = client.request(method, f"/api/v1/campaigns/{BIG}/plan", json=SMALL, headers=AUTH)
        assert r.status_code == 422, (method, r.text)
        assert r.json()["detail"][0]["loc"] == ["path", "campaign_id"], r.text
    cid = _campaign(client)
    bad = [
        ({"anchor_ids": [" "]}, ["body", "anchor_ids", 0]),
        ({"anchor_ids": [""]}, ["body", "anchor_ids", 0]),
        ({"anchor_ids": ["A" * 33]}, ["body", "anchor_ids", 0]),
        ({"anchor_ids": ["A"] * 5}, ["body", "anchor_ids"]),
        ({"start_from_samples": "yes"}, ["body", "start_from_samples"]),
        ({"n": "8"}, ["body", "n"]),
        ({"anchors_mm": [[1.0, 2.0, 3.0, 4.0]]}, ["body", "anchors_mm", 0]),
    ]
    for change, loc in bad:
        r = client.post(f"/api/v1/campaigns/{cid}/plan", json={**SMALL, **change}, headers=AUTH)
        assert r.status_code == 422, (change, r.text)
        assert r.json()["detail"][0]["loc"] == loc, (change, r.text)
    # NaN (which Python's JSON reader accepts) is not a coordinate.
    r = client.post(
        f"/api/v1/campaigns/{cid}/plan",
        content=b'{"anchors_mm": [[NaN, 0, 0]], "n": 8, "candidates": 200}',
        headers={**AUTH, "Content-Type": "application/json"},
    )
    assert r.status_code == 422, r.text
    r = client.get(f"/api/v1/campaigns/{cid}/plan", params={"tol_deg": "nan"}, headers=AUTH)
    assert r.status_code == 422, r.text


def test_openapi_declares_the_plan_routes_statuses(client: TestClient) -> None:
    spec = client.get("/openapi.json").json()["paths"]["/api/v1/campaigns/{campaign_id}/plan"]
    assert {"400", "401", "404", "409", "413", "422"} <= set(spec["post"]["responses"])
    assert {"401", "404", "413", "422"} <= set(spec["get"]["responses"])


def test_plan_downloads_as_csv_and_robot_programs(client: TestClient) -> None:
    from calib.programs import DOWNLOAD_FORMATS, dwell_s_for_settle
    from calib.programs.formats import LANGUAGES
    from calib.programs.registry import parse_program

    cid = _campaign(client)
    r = client.post(f"/api/v1/campaigns/{cid}/plan", json=SMALL, headers=AUTH)
    assert r.status_code == 201, r.text
    planned = [_q(p) for p in r.json()["poses"]]
    url = f"/api/v1/campaigns/{cid}/plan"
    for fmt in DOWNLOAD_FORMATS:
        r = client.get(url, headers=AUTH, params={"format": fmt})
        assert r.status_code == 200, r.text
        assert 'filename="campaign' in r.headers["content-disposition"].lower()
        if fmt == "csv":
            lines = r.text.splitlines()
            assert lines[0].startswith("pose,q1,q2") and len(lines) == 1 + len(planned)
            continue
        back = parse_program(fmt, r.text)
        # The language's own line ends, as the CLI writes them (Fanuc's .LS: CRLF only).
        crlf = LANGUAGES[fmt].newline == "\r\n"
        assert r.content.count(b"\r\n") == (r.content.count(b"\n") if crlf else 0), fmt
        assert len(back.joints_deg) == len(planned)
        for got, want in zip(back.joints_deg, planned, strict=True):
            assert max(abs(a - b) for a, b in zip(got, want, strict=True)) <= 0.0005 + 1e-9
        # The default dwell follows the daemon's settle window.
        settle_s = client.app.state.cablecal.settings.sampler.settle_s  # type: ignore[attr-defined]
        assert back.dwell_s == dwell_s_for_settle(settle_s) > 2 * settle_s
    for bad in ({"format": "gcode"}, {"format": "krl", "speed_pct": 0}):
        r = client.get(url, headers=AUTH, params=bad)
        assert r.status_code == 422, r.text
    r = client.get(url, headers=AUTH, params={"format": "krl", "anchor": "Z"})
    # An anchor the plan lacks is the campaign's state (404, named), not a malformed request.
    assert r.status_code == 404 and "anchor: 'Z' is not in plan" in r.json()["detail"], r.text
    r = client.get(url, headers=AUTH, params={"format": "krl", "anchor": "A"})
    assert r.status_code == 200 and "plan_A.src" in r.headers["content-disposition"]


def test_a_plan_that_identifies_no_robot_parameter_is_a_clear_422_not_a_500(
    client: TestClient,
) -> None:
    """Regression (schemathesis, after the plan-noise merge): one candidate pose gave a
    ZeroDivisionError (500) in the design's per-parameter log det."""
    cid = _campaign(client)
    body = {
        "anchors_mm": [[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]],
        "anchor_uncertainty_mm": 0.0,
        "candidates": 1,
        "dwell_s": 0.0,
        "n": 1,
    }
    r = client.post(f"/api/v1/campaigns/{cid}/plan", json=body, headers=AUTH)
    assert r.status_code == 422, r.text
    assert "candidates" in r.text and "identify none" in r.text
