"""Issue 27 item 2: the plan knows the indicator's range. The planner keeps each pose's
predicted reading (cable extension + the indicator's zero offset) inside 0..2000 mm with a
margin; a planned pose the sampler refuses for good is marked "not capturable" and counted
apart; the result's plan check never asks for it."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient
from test_service import AUTH, TOKEN, FakeSampler, _settings

from calib.dataset import CABLE_MAX_MM, CABLE_MIN_MM, READING_MARGIN_MM
from calib.models import builtin_model
from calib.planning import PlanOptions, plan
from calib.planning.candidates import flange_and_tool_mm, reading_window_mm
from calib.planning.progress import not_capturable, plan_check
from calib.tcp import workspace_sample_deg
from daemon.api.main import create_app

MODEL = builtin_model("hsr-jr680")
ANCHOR = np.array([1400.0, 300.0, 200.0])
#: The zero offset of the issue's cell: readings 0 at 300 mm of cable, so a pose closer to the
#: sensor than that reads below 0 (over range).
OFFSET_MM = -300.0


def _readings(q_deg: np.ndarray, offset_mm: float) -> np.ndarray:
    return np.linalg.norm(flange_and_tool_mm(MODEL, q_deg)[1] - ANCHOR, axis=1) + offset_mm


def test_the_planner_keeps_every_predicted_reading_inside_the_range() -> None:
    opts = PlanOptions(n=40, candidates=800, seed=3)
    blind = plan(MODEL, ANCHOR, opts)
    # Without the offset the planner cannot know: some of its poses read below 0 (the test
    # can fail) ...
    assert (_readings(blind.q_deg, OFFSET_MM) < CABLE_MIN_MM).any()
    assert blind.to_json()["reading_mm"] is None
    # ... with it, every pose reads inside the range less the margins.
    known = plan(MODEL, ANCHOR, PlanOptions(n=40, candidates=800, seed=3, offsets_mm=(OFFSET_MM,)))
    lo, hi = reading_window_mm(opts.anchor_uncertainty_mm)
    assert (lo, hi) == (
        CABLE_MIN_MM + READING_MARGIN_MM + 30.0,
        CABLE_MAX_MM - READING_MARGIN_MM - 30.0,
    )
    readings = _readings(known.q_deg, OFFSET_MM)
    assert readings.min() >= lo and readings.max() <= hi
    np.testing.assert_allclose(known.readings_mm(), readings)
    summary = known.to_json()["reading_mm"]
    assert summary["offsets_mm"] == {"A": OFFSET_MM} and summary["window_mm"] == [lo, hi]
    assert summary["min"] == pytest.approx(readings.min())
    # the plan is still a plan: its predicted TCP σ is no worse than 1.5x the blind one's
    assert known.tcp.rms_mm <= 1.5 * blind.tcp.rms_mm


def test_an_offset_that_leaves_no_reachable_pose_is_a_clear_error() -> None:
    with pytest.raises(ValueError, match=r"reading within 40\.\.1960 mm at zero offset -2500\.0"):
        plan(MODEL, ANCHOR, PlanOptions(n=10, candidates=100, offsets_mm=(-2500.0,)))
    with pytest.raises(ValueError, match="offsets_mm: 2 offsets for 1 anchors"):
        plan(MODEL, ANCHOR, PlanOptions(n=10, candidates=100, offsets_mm=(0.0, 0.0)))


def _pose(i: int, q: list[float]) -> dict[str, Any]:
    return {"pose": i, "anchor": "A", **{f"q{j + 1}": v for j, v in enumerate(q)}}


def test_refused_poses_are_not_capturable_and_the_plan_check_never_asks_for_them() -> None:
    rng = np.random.default_rng(0)
    qs = rng.uniform(-90, 90, (4, 6)).round(3).tolist()
    poses = [_pose(i + 1, q) for i, q in enumerate(qs)]
    refused = [
        {"reason": "over_range", "detail": "indicator reads -243.5 mm", "joints_deg": qs[2]},
        {"reason": "stale", "detail": "reading 2 s old", "joints_deg": qs[3]},  # may pass later
        {"reason": "over_range", "detail": "no pose"},  # refused before poses were recorded
    ]
    match = [0, 1, -1, -1]
    assert not_capturable(poses, match, refused) == [
        None,
        None,
        "over_range: indicator reads -243.5 mm",
        None,
    ]
    # a measured pose is never marked, even if it was refused once
    assert not_capturable(poses, [0, 1, 2, -1], refused)[2] is None
    plan_row = {"id": 7, "poses": poses, "summary": {"tcp_sigma_mm": {"plan": {"rms": 0.02}}}}
    result = {"tcp_uncertainty_mm": {"rms": 0.021}, "prior": {"noise_mm": 0.02}}
    # poses 1, 2 and 4 measured, pose 3 refused: on plan, and said so
    check = plan_check(plan_row, [qs[0], qs[1], qs[3]], ["A"] * 3, result, refused)
    assert check["on_plan"] and check["n_not_capturable"] == 1 and check["n_measured"] == 3
    assert "capture the pending" not in check["note"]
    assert "all 3 capturable planned poses" in check["note"]
    assert "1 planned pose(s) cannot be captured (pose 3" in check["note"]
    # pose 4 still to capture: the note asks for pending poses and sets pose 3 apart
    check = plan_check(plan_row, [qs[0], qs[1]], ["A"] * 2, result, refused)
    assert not check["on_plan"] and "capture the pending poses" in check["note"]
    assert "cannot be captured (pose 3" in check["note"]


@pytest.fixture(scope="module")
def client(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TestClient]:
    settings = _settings(tmp_path_factory.mktemp("range"))
    app = create_app(settings, TOKEN, sampler_factory=FakeSampler)
    with TestClient(app) as c:
        yield c


def test_the_api_marks_a_refused_pose_and_plans_with_the_samples_offset(
    client: TestClient,
) -> None:
    r = client.post(
        "/api/v1/campaigns", json={"name": "r", "robot_model": "hsr-jr680"}, headers=AUTH
    )
    cid = int(r.json()["id"])
    # 30 samples at the anchor, zero offset -300 mm (the nominal robot's lengths)
    q = workspace_sample_deg(MODEL, 200, seed=4)
    keep = q[(_readings(q, OFFSET_MM) > 100) & (_readings(q, OFFSET_MM) < 1900)][:30]
    assert len(keep) == 30
    lengths = _readings(keep, OFFSET_MM)
    csv = "q1,q2,q3,q4,q5,q6,L\n" + "".join(
        ",".join(f"{v:.4f}" for v in (*row, length)) + "\n"
        for row, length in zip(keep, lengths, strict=True)
    )
    r = client.post(
        f"/api/v1/campaigns/{cid}/samples/import",
        content=csv,
        headers={**AUTH, "Content-Type": "text/csv"},
    )
    assert r.status_code == 201, r.text
    body = {"n": 10, "candidates": 300, "seed": 1, "start_from_samples": True}
    r = client.post(f"/api/v1/campaigns/{cid}/plan", json=body, headers=AUTH)
    assert r.status_code == 201, r.text
    made = r.json()
    reading = made["summary"]["reading_mm"]
    assert reading["offsets_mm"]["A"] == pytest.approx(OFFSET_MM, abs=1.0)
    assert reading["offset_source"] == {"A": "the campaign's samples"}
    lo, hi = reading["window_mm"]
    assert lo <= reading["min"] and reading["max"] <= hi
    for p in made["poses"]:
        assert lo - 1.0 <= p["extension_mm"] + OFFSET_MM <= hi + 1.0, p

    # The sampler refuses pose 2 (over range) and pose 3 (a stale reading: may pass later).
    store = client.app.state.cablecal.store  # type: ignore[attr-defined]
    poses = made["poses"]
    joints = [[p[f"q{j}"] for j in range(1, 7)] for p in poses]
    store.record_rejection(
        cid, "over_range", "indicator over range", "indicator", joints_deg=joints[1]
    )
    store.record_rejection(cid, "stale", "reading 2 s old", "indicator", joints_deg=joints[2])
    got = client.get(f"/api/v1/campaigns/{cid}/plan", headers=AUTH).json()
    assert got["poses"][1]["status"] == "not_capturable"
    assert got["poses"][1]["why"] == "over_range: indicator over range"
    assert got["poses"][2]["status"] == "pending" and got["poses"][2]["why"] is None
    progress = got["progress"]
    assert progress["n_not_capturable"] == 1 and progress["n_pending"] == len(poses) - 1
    assert progress["next_pose"] == 1


def test_a_refusal_through_the_watched_sink_is_stored_with_the_robots_pose(
    tmp_path: Any,
) -> None:
    """The sampler hands a refusal over with its robot's newest joints
    (tests/test_sampler.py); the watched sink, the sampler's sink in the daemon, stores them."""
    from calib.monitor.stepwatch import StepSettings
    from daemon.monitors.watch import SensorWatch
    from daemon.store import Store

    store = Store(tmp_path / "s.sqlite3")
    try:
        robot = store.ensure_builtin_robot("hsr-jr680")
        cid = int(store.create_campaign("c", robot["id"])["id"])
        sink = SensorWatch(store, StepSettings()).wrap(store)
        pose = (1.0, 2.0, 3.0, 4.0, 5.0, 6.0)
        sink.record_rejection(cid, "over_range", "indicator over range", "indicator", pose)
        (event,) = store.list_events(kind="capture_rejected", campaign_id=cid)
        assert event["detail"] == {
            "reason": "over_range",
            "detail": "indicator over range",
            "joints_deg": [1.0, 2.0, 3.0, 4.0, 5.0, 6.0],
        }
        assert event["message"] == "over_range: indicator over range"
        sink.record_rejection(cid, "stale", "old", "indicator")  # no reading: no pose
        assert "joints_deg" not in store.list_events(kind="capture_rejected")[-1]["detail"]
    finally:
        store.close()
