"""The one WHERE-filter builder and page limit of the store's list methods
(:func:`daemon.store.db.where_clause`, :func:`check_limit`, ``StoreDB._page``), and every list
method that uses them: campaigns, samples, jobs, checks, events."""

from __future__ import annotations

from typing import Any

import pytest
from _store_helpers import ROBOT, fake_result, make_capture

from daemon.api.deps import PAGE_MAX
from daemon.store import Store, StoreInvalid
from daemon.store.db import MAX_PAGE_ROWS, check_limit, where_clause

POSE_DEG = (0.0, -30.0, 180.0, 0.0, 30.0, 0.0)


def test_where_clause_skips_none_and_keeps_order() -> None:
    assert where_clause([]) == ("", [])
    assert where_clause([("a = ?", None), ("b > ?", None)]) == ("", [])
    assert where_clause([("a = ?", "x"), ("b = ?", None), ("c > ?", 0)]) == (
        " WHERE a = ? AND c > ?",
        ["x", 0],
    )


@pytest.mark.parametrize("limit", [0, -1, MAX_PAGE_ROWS + 1])
def test_check_limit_refuses_out_of_range(limit: int) -> None:
    with pytest.raises(StoreInvalid, match=rf"^limit: must be within 1\.\.10000, got {limit}$"):
        check_limit(limit)


def test_check_limit_bounds_pass_and_api_shares_them() -> None:
    assert check_limit(1) == 1 and check_limit(MAX_PAGE_ROWS) == MAX_PAGE_ROWS
    assert PAGE_MAX == MAX_PAGE_ROWS


def test_campaign_pages_follow_the_cursor(store: Store) -> None:
    rid = store.ensure_builtin_robot(ROBOT)["id"]
    ids = [store.create_campaign(f"c{k}", rid)["id"] for k in range(5)]
    assert [c["id"] for c in store.list_campaigns()] == ids
    assert [c["id"] for c in store.list_campaigns(limit=2)] == ids[:2]
    assert [c["id"] for c in store.list_campaigns(after_id=ids[1], limit=2)] == ids[2:4]
    assert [c["id"] for c in store.list_campaigns(after_id=ids[3], limit=2)] == ids[4:]
    assert store.list_campaigns(after_id=ids[4]) == []
    with pytest.raises(StoreInvalid, match="limit"):
        store.list_campaigns(limit=0)


def test_sample_pages_and_the_excluded_filter(store: Store, campaign: dict[str, Any]) -> None:
    cid = campaign["id"]
    ids = [store.store_capture(cid, make_capture(POSE_DEG, 900.0 + k))["id"] for k in range(4)]
    store.set_excluded(ids[1], True, "bump")
    assert [s["id"] for s in store.list_samples(cid)] == ids
    assert [s["id"] for s in store.list_samples(cid, include_excluded=False)] == [
        ids[0],
        ids[2],
        ids[3],
    ]
    assert [s["id"] for s in store.list_samples(cid, after_id=ids[0], limit=2)] == ids[1:3]
    page = store.list_samples(cid, include_excluded=False, after_id=ids[0], limit=1)
    assert [s["id"] for s in page] == [ids[2]]
    other = store.create_campaign("other", campaign["robot_id"])["id"]
    assert store.list_samples(other) == []


def test_job_pages_by_campaign(store: Store, campaign: dict[str, Any]) -> None:
    cid, rid = campaign["id"], campaign["robot_id"]
    other = store.create_campaign("other", rid)["id"]
    mine = [store.create_job(cid, rid, "lm", {})["id"] for _ in range(3)]
    theirs = store.create_job(other, rid, "lm", {})["id"]
    assert [j["id"] for j in store.list_jobs()] == [*mine, theirs]
    assert [j["id"] for j in store.list_jobs(cid, after_id=mine[0])] == mine[1:]
    assert [j["id"] for j in store.list_jobs(after_id=mine[1], limit=1)] == [mine[2]]
    assert [j["id"] for j in store.list_jobs(other)] == [theirs]


def test_checks_newest_first_page_filtered_by_robot_and_status(
    store: Store, campaign: dict[str, Any]
) -> None:
    cid, rid = campaign["id"], campaign["robot_id"]
    result_id = store.save_result(store.create_job(cid, rid, "lm", {})["id"], fake_result(0.0))[
        "id"
    ]
    ids = [
        store.create_check(
            rid,
            cid,
            result_id,
            trigger="manual",
            threshold_mm=0.5,
            refit_anchor=False,
            poses_deg=[POSE_DEG],
        )["id"]
        for _ in range(4)
    ]
    store.finish_check(ids[0], "ok", metrics={"n": 1, "rmse_mm": 0.1})
    store.finish_check(ids[2], "not_held", metrics={"n": 1, "rmse_mm": 0.9})
    assert [c["id"] for c in store.list_checks()] == ids
    assert [c["id"] for c in store.list_checks(limit=2)] == ids[2:]  # newest, oldest first
    assert [c["id"] for c in store.list_checks(status="running")] == [ids[1], ids[3]]
    assert [c["id"] for c in store.list_checks(rid, status="ok")] == [ids[0]]
    assert store.list_checks(rid + 1) == []
    with pytest.raises(StoreInvalid, match="limit"):
        store.list_checks(limit=MAX_PAGE_ROWS + 1)


def test_events_follow_after_since_id_or_give_the_newest(store: Store) -> None:
    for k in range(5):
        store.record_event(
            "link_down" if k % 2 else "link_up",
            "indicator",
            f"e{k}",
            campaign_id=7 if k >= 3 else None,
        )
    ids = [e["id"] for e in store.list_events()]
    assert len(ids) == 5
    assert [e["message"] for e in store.list_events(limit=2)] == ["e3", "e4"]
    assert [e["message"] for e in store.list_events(since_id=ids[0], limit=2)] == ["e1", "e2"]
    assert [e["message"] for e in store.list_events(kind="link_down")] == ["e1", "e3"]
    assert [e["message"] for e in store.list_events(kind="link_up", campaign_id=7)] == ["e4"]
    follow = store.list_events(kind="link_up", since_id=ids[0])
    assert [e["message"] for e in follow] == ["e2", "e4"]
