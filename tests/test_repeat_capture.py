"""Issue 27 item 8: one rule for a repeated capture, auto and manual
(:func:`calib.dataset.known_pose_index`): auto capture skips a pose the campaign has; a manual
capture there is refused with the reason (409 ``not_new_pose``, naming the sample) unless
the operator confirms it (``repeat``); the operator page asks."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest
from fastapi.testclient import TestClient
from test_service import AUTH, TOKEN, FakeSampler, _campaign, _settings

from calib.dataset import known_pose_index
from daemon.api.main import create_app
from daemon.sampler.config import SamplerConfig

POSE = [10.0, -60.0, 200.0, -170.0, 40.0, 60.0]


def test_known_pose_index_is_every_joint_within_the_tolerance() -> None:
    known = np.array([[0.0] * 6, POSE])
    tol = SamplerConfig().auto_new_pose_deg
    assert known_pose_index(known, POSE, tol) == 1
    near = np.array(POSE) + 0.9 * tol
    assert known_pose_index(known, near, tol) == 1
    off = np.array(POSE)
    off[5] += 1.1 * tol  # one joint beyond the tolerance: a new pose
    assert known_pose_index(known, off, tol) is None
    assert known_pose_index(np.empty((0, 6)), POSE, tol) is None


@pytest.fixture(scope="module")
def client(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TestClient]:
    settings = _settings(tmp_path_factory.mktemp("repeat"))
    app = create_app(settings, TOKEN, sampler_factory=FakeSampler)
    with TestClient(app) as c:
        yield c


def test_a_manual_repeat_is_refused_with_the_reason_unless_confirmed(client: TestClient) -> None:
    cid = _campaign(client, "repeat")
    url = f"/api/v1/campaigns/{cid}/captures"
    first = client.post(url, json={"joints_deg": POSE}, headers=AUTH)
    assert first.status_code == 201, first.text
    again = client.post(url, json={"joints_deg": POSE}, headers=AUTH)
    assert again.status_code == 409, again.text
    detail = again.json()["detail"]
    assert detail["reason"] == "not_new_pose"
    assert f"sample {first.json()['id']}" in detail["detail"] and "repeat" in detail["detail"]
    assert len(client.get(f"/api/v1/campaigns/{cid}/samples", headers=AUTH).json()) == 1
    confirmed = client.post(url, json={"joints_deg": POSE, "repeat": True}, headers=AUTH)
    assert confirmed.status_code == 201, confirmed.text
    moved = [v + 1.0 for v in POSE]  # a new pose needs no confirmation
    assert client.post(url, json={"joints_deg": moved}, headers=AUTH).status_code == 201
    assert len(client.get(f"/api/v1/campaigns/{cid}/samples", headers=AUTH).json()) == 3
    bad = client.post(url, json={"joints_deg": POSE, "repeat": "yes"}, headers=AUTH)
    assert bad.status_code == 422  # strict: JSON true or false only
