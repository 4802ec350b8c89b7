"""The samples a campaign needs before identify: computed from calib's rule for the robot and
the anchors of the included samples, cached, and carried by the campaign JSON."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient
from test_service import AUTH, TOKEN, FakeSampler

from calib.dataset import SampleError, SampleSet, make_samples, samples_to_csv
from calib.min_samples import min_samples
from calib.models import builtin_model
from calib.options import IdentifyOptions, check_training_rows, validate
from daemon.api.main import create_app
from daemon.api.min_samples import MinSamplesCache
from daemon.config import Settings
from daemon.datafiles import read_samples

MODEL = builtin_model("hsr-jr680")
API = "/api/v1"


def _anchored(n: int, anchors: str) -> SampleSet:
    """The first ``n`` rows of the bundled dataset, the anchors taking turns."""
    s = read_samples(None).subset(np.arange(n))
    return make_samples(s.joints_deg, s.length_mm, [anchors[i % len(anchors)] for i in range(n)])


@pytest.mark.parametrize(
    ("anchors", "values"),
    [("A", {}), ("AB", {}), ("ABC", {}), ("AB", {"test_fraction": 0.5}), ("A", {"fix": ("a2",)})],
)
def test_the_minimum_is_where_validate_starts_to_accept(
    anchors: str, values: dict[str, Any]
) -> None:
    opts = IdentifyOptions(**values)
    need = min_samples(MODEL, len(anchors), opts)
    validate(_anchored(need.samples, anchors), opts, model=MODEL)
    with pytest.raises(SampleError, match=r"training samples"):
        validate(_anchored(need.samples - 1, anchors), opts, model=MODEL)
    check_training_rows(need.training_samples, need.training_samples, need.n_params)
    with pytest.raises(SampleError):
        check_training_rows(need.training_samples - 1, need.samples, need.n_params)


def test_each_further_anchor_needs_more_samples() -> None:
    one, two, three = (min_samples(MODEL, k) for k in (1, 2, 3))
    assert (one.samples, one.training_samples) == (31, 25)  # README: 25 training rows, 31 at 0.2
    assert two.n_params - one.n_params == 4 == three.n_params - two.n_params
    assert one.samples < two.samples < three.samples
    assert min_samples(MODEL, 0) == one  # no samples yet: the first capture brings one anchor
    with pytest.raises(ValueError, match="n_anchors"):
        min_samples(MODEL, -1)


def test_the_cache_computes_once_per_robot_and_anchor_count() -> None:
    class Store:
        loads = 0

        def robot_model(self, robot_id: int) -> Any:
            Store.loads += 1
            return MODEL

    cache = MinSamplesCache(Store())  # type: ignore[arg-type]
    first = cache.get(1, 1)
    for _ in range(50):
        assert cache.get(1, 1) is first and cache.get(1, 0) is first
    assert Store.loads == 1
    assert cache.get(1, 2).samples > first.samples and Store.loads == 2


@pytest.fixture(scope="module")
def client(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TestClient]:
    settings = Settings(state_dir=tmp_path_factory.mktemp("min"), api_token=TOKEN)
    with TestClient(create_app(settings, TOKEN, sampler_factory=FakeSampler)) as c:
        yield c


def _import(client: TestClient, cid: int, samples: SampleSet) -> None:
    r = client.post(
        f"{API}/campaigns/{cid}/samples/import",
        content=samples_to_csv(samples),
        headers={**AUTH, "Content-Type": "text/csv"},
    )
    assert r.status_code == 201, r.text


def test_the_campaign_says_how_many_samples_identify_needs(client: TestClient) -> None:
    one, two = min_samples(MODEL, 1), min_samples(MODEL, 2)
    r = client.post(
        f"{API}/campaigns", json={"name": "m", "robot_model": "hsr-jr680"}, headers=AUTH
    )
    assert r.status_code == 201
    made = r.json()
    cid = made["id"]
    assert made["anchors"] == [] and made["min_samples_to_identify"] == one.samples
    assert made["min_training_samples"] == one.training_samples
    assert made["recommended_samples"] == one.recommended_samples > one.samples  # issue 22
    # Two anchors, one sample short of what they need: the campaign says so, and the
    # submission is refused by the same rule.
    _import(client, cid, _anchored(two.samples - 1, "AB"))
    got = client.get(f"{API}/campaigns/{cid}", headers=AUTH).json()
    assert got["anchors"] == ["A", "B"] and got["n_included"] == two.samples - 1
    assert got["min_samples_to_identify"] == two.samples
    assert got["min_training_samples"] == two.training_samples
    assert got["recommended_samples"] == two.recommended_samples
    listed = {c["id"]: c for c in client.get(f"{API}/campaigns", headers=AUTH).json()}
    assert listed[cid] == got
    r = client.post(f"{API}/campaigns/{cid}/identifications", json={}, headers=AUTH)
    assert r.status_code == 409 and f"need at least {two.training_samples}" in r.text, r.text
    # Excluded samples do not count: without the B samples one anchor is left.
    for s in client.get(f"{API}/campaigns/{cid}/samples", headers=AUTH).json():
        if s["anchor"] == "B":
            client.patch(f"{API}/samples/{s['id']}", json={"excluded": True}, headers=AUTH)
    got = client.get(f"{API}/campaigns/{cid}", headers=AUTH).json()
    assert got["anchors"] == ["A"] and got["min_samples_to_identify"] == one.samples
