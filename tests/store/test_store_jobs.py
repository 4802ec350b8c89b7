"""Jobs, results, the calibrated model and the event log in the store."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from _store_helpers import ROBOT, fake_result

from calib.dataset import parse_samples_csv
from daemon.store import INTERRUPTED_ERROR, Store, StoreError, StoreInvalid, StoreNotFound


# ----------------------------------------------------------------------- jobs/results
def test_jobs_lifecycle_and_mark_interrupted(tmp_path: Path) -> None:
    path = tmp_path / "db.sqlite3"
    with Store(path) as s:
        rid = s.ensure_builtin_robot(ROBOT)["id"]
        cid = s.create_campaign("c", rid)["id"]
        queued = s.create_job(cid, rid, "ukf-vslm", {"seed": 1, "fix": ["a1"]})
        assert queued["status"] == "queued" and queued["progress"]["fraction"] == 0.0
        assert queued["interrupted"] is False
        assert queued["options"] == {"seed": 1, "fix": ["a1"]}
        running = s.update_job(
            s.create_job(cid, rid, "lm", {})["id"],
            status="running",
            progress=0.4,
            message="epoch 1",
        )
        assert running["started_at"] is not None and running["progress"]["fraction"] == 0.4
        done = s.create_job(cid, rid, "lm", {})["id"]
        s.update_job(done, status="running")
        finished = s.update_job(done, status="succeeded", progress=1.0)
        assert finished["finished_at"] >= finished["started_at"]
        with pytest.raises(StoreInvalid, match="progress"):
            s.update_job(done, progress=1.5)
        with pytest.raises(StoreInvalid, match="status"):
            s.update_job(done, status="exploded")
        stepped = s.update_job(done, iteration=3, cost_rms_mm=0.25)
        assert stepped["progress"] == {"fraction": 1.0, "iteration": 3, "cost_rms_mm": 0.25}
        with pytest.raises(StoreInvalid, match="iteration"):
            s.update_job(done, iteration=-1)
        with pytest.raises(StoreInvalid, match="cost_rms_mm"):
            s.update_job(done, cost_rms_mm=float("nan"))
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
        jobs[1],
        second["id"],
        cid,
    )
    assert latest["robot"] == ROBOT and latest["convention"] == "dh"
    assert latest["dh"][0]["a_mm"] == 102.0 and latest["tool_mm"] == [0.0, 0.0, 52.0]
    assert latest["metrics"]["test"]["rmse_mm"] == pytest.approx(2.1)
    # Exactly one current calibration per robot: the robot row and the job rows agree.
    assert store.robot(rid)["current_identification_id"] == jobs[1]
    assert [j["current"] for j in store.list_jobs(cid)] == [False, True, False]
    assert store.get_result_for_job(jobs[2])["current"] is False  # type: ignore[index]
    store.set_result_accepted(second["id"], False)
    latest = store.latest_calibrated_model(rid)
    assert latest is not None and latest["job_id"] == jobs[0]
    assert [j["current"] for j in store.list_jobs(cid)] == [True, False, False]
    third = store.get_result_for_job(jobs[2])
    assert third is not None
    assert store.set_result_accepted(third["id"], True)["current"] is True
    assert store.robot(rid)["current_identification_id"] == jobs[2]
    assert [j["current"] for j in store.list_jobs(cid)] == [False, False, True]
    store.set_result_accepted(third["id"], False)
    got = store.get_result_for_job(jobs[2])
    assert got is not None and got["accepted"] is False and got["current"] is False
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
    store.record_event(
        "link_down", "indicator", "timeout", {"frames_hex": ["01 03"], "raw": b"\x01"}
    )
    store.record_rejection(campaign["id"], "moving", "q2 moved 0.3 deg", "robot")
    store.record_rejection(999, "stale", "indicator reading 2.1 s old", "indicator")
    store.record_event("link_up", "indicator", "reconnected", {"age_s": math.inf})
    events = store.list_events()
    assert [e["kind"] for e in events] == [
        "sampler_started",
        "link_down",
        "capture_rejected",
        "capture_rejected",
        "link_up",
    ]
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
