"""Samples move between anchor sessions (the live watch's split and its undo)."""

from __future__ import annotations

from typing import Any

import pytest
from _store_helpers import make_capture

from daemon.store import Store, StoreInvalid, StoreNotFound


def test_samples_move_to_another_anchor_and_back(store: Store, campaign: dict[str, Any]) -> None:
    cid = campaign["id"]
    ids = [
        int(store.store_capture(cid, make_capture((0, -10 * k, 10, 0, 20, 0), 800.0 + k))["id"])
        for k in range(4)
    ]
    assert store.move_samples_to_anchor(cid, ids[2:], "A2") == 2
    assert [s["anchor"] for s in store.list_samples(cid)] == ["A", "A", "A2", "A2"]
    assert store.campaign(cid)["anchors"] == ["A", "A2"]
    assert store.move_samples_to_anchor(cid, ids[2:], "A") == 2
    assert store.campaign(cid)["anchors"] == ["A"]


def test_a_bad_move_changes_nothing(store: Store, campaign: dict[str, Any]) -> None:
    cid = campaign["id"]
    sid = int(store.store_capture(cid, make_capture((0, -10, 10, 0, 20, 0), 800.0))["id"])
    other = store.create_campaign("cell 2", campaign["robot_id"])
    row = store.store_capture(other["id"], make_capture((0, -5, 10, 0, 20, 0), 801.0))
    foreign = int(row["id"])
    with pytest.raises(StoreInvalid, match="sample_ids"):
        store.move_samples_to_anchor(cid, [sid, foreign], "A2")
    with pytest.raises(StoreInvalid, match="anchor"):
        store.move_samples_to_anchor(cid, [sid], " ")
    with pytest.raises(StoreNotFound):
        store.move_samples_to_anchor(9999, [sid], "A2")
    assert store.sample(sid)["anchor"] == "A" and store.sample(foreign)["anchor"] == "A"
