"""Issue 32 items 3 and 10: the filter download is what the preview showed. The preview
(dry run) names the robot, the calibration (identification id and date) and a digest of the
filtered files; a download with them returns exactly those files or a 409 when the robot's
calibration changed in between (tab B accepted another) or the files differ; every output
names the robot and the calibration; one bad file does not block the good ones."""

# ruff: noqa: F811  (the fixtures of test_api_apply are imported, then named as arguments)

from __future__ import annotations

import io
import json
import time
import zipfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient
from test_api_apply import calibrated, cell  # noqa: F401
from test_service import AUTH, TOKEN, FakeSampler

from daemon.api.main import create_app
from daemon.api.routes.robots.program_filter import outputs_digest
from daemon.config import Settings

API = "/api/v1"
FIXTURES = Path(__file__).parent / "fixtures" / "programs"
BAD = ("bad.mod", b"MODULE B\n  CONST robtarget p:=[[1,2],[1,0,0,0]];\nENDMODULE\n")


@pytest.fixture(scope="module")
def client(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TestClient]:
    tmp = tmp_path_factory.mktemp("preview")
    settings = Settings(state_dir=tmp, api_token=TOKEN)
    with TestClient(create_app(settings, TOKEN, sampler_factory=FakeSampler)) as c:
        yield c


def _files(*names: str, extra: tuple[str, bytes] | None = None) -> list[Any]:
    out: list[Any] = [
        ("files", (n, (FIXTURES / n).read_bytes(), "application/octet-stream")) for n in names
    ]
    if extra is not None:
        out.append(("files", (extra[0], extra[1], "text/plain")))
    return out


def _filter(client: TestClient, rid: int, files: list[Any], **params: Any) -> Any:
    return client.post(f"{API}/robots/{rid}/filter", files=files, params=params, headers=AUTH)


def _accept_another(client: TestClient, campaign_id: int) -> int:
    r = client.post(
        f"{API}/campaigns/{campaign_id}/identifications",
        json={"method": "lm", "test_fraction": 0.25, "seed": 3},
        headers=AUTH,
    )
    job_id = int(r.json()["id"])
    deadline = time.monotonic() + 120
    while client.get(f"{API}/identifications/{job_id}", headers=AUTH).json()["status"] not in (
        "succeeded",
        "failed",
    ):
        assert time.monotonic() < deadline
        time.sleep(0.2)
    if not client.get(f"{API}/identifications/{job_id}", headers=AUTH).json()["current"]:
        r = client.post(f"{API}/identifications/{job_id}/accept", headers=AUTH)
        assert r.status_code == 200, r.text
    return job_id


def test_the_download_is_the_preview_or_a_409(
    client: TestClient, calibrated: dict[str, int]
) -> None:
    rid, job = calibrated["robot_id"], calibrated["job_id"]
    names = ("cell_a.mod", "polyscope_c.script")
    # before: the preview names the robot, the calibration and its date, and a digest
    preview = _filter(client, rid, _files(*names), dry_run="true").json()
    assert preview["calibration_id"] == job and preview["robot_id"] == rid
    assert preview["robot"] == "hsr-jr680" and preview["robot_model"] == "hsr-jr680"
    assert len(preview["calibration_date"]) == 25 and len(preview["digest"]) == 64
    # action: the download with the preview's calibration and digest
    keys = {"calibration_id": job, "digest": preview["digest"]}
    r = _filter(client, rid, _files(*names), **keys)
    assert r.status_code == 200, r.text
    assert (
        f"calibration-{job}-{preview['calibration_date'][:10]}" in r.headers["content-disposition"]
    )
    assert r.headers["x-filter-calibration-id"] == str(job)
    assert r.headers["x-filter-calibration-date"] == preview["calibration_date"]
    assert r.headers["x-filter-robot"] == "hsr-jr680"
    with zipfile.ZipFile(io.BytesIO(r.content)) as zf:
        got = {n: zf.read(n) for n in zf.namelist()}
        comment = zf.comment.decode()
    summary = json.loads(got.pop("filter-summary.json"))
    # after: exactly what was shown (the same digest of the same files), named
    assert outputs_digest(got) == preview["digest"]
    assert summary["calibration_id"] == job and summary["robot"] == "hsr-jr680"
    assert f"calibration #{job} of {preview['calibration_date']}" in comment
    assert "robot hsr-jr680" in comment
    # other files than the preview's under its digest: refused
    r = _filter(client, rid, _files("cell_a.mod"), **keys)
    assert r.status_code == 409 and "differ from the preview" in r.json()["detail"]
    # tab B accepts another calibration: tab A's download is refused, not silently other
    newer = _accept_another(client, calibrated["campaign_id"])
    r = _filter(client, rid, _files(*names), **keys)
    assert r.status_code == 409, r.text
    detail = r.json()["detail"]
    assert f"#{job} was shown, #{newer}" in detail and "preview the files again" in detail
    assert _filter(client, rid, _files(*names), dry_run="true").json()["calibration_id"] == newer
    # put the first one back for the other tests of the module
    assert client.post(f"{API}/identifications/{job}/accept", headers=AUTH).status_code == 200


def test_one_bad_file_does_not_block_the_good_ones(
    client: TestClient, calibrated: dict[str, int]
) -> None:
    rid = calibrated["robot_id"]
    r = _filter(client, rid, _files("cell_a.mod", extra=BAD), dry_run="true")
    assert r.status_code == 200, r.text
    summary = r.json()
    assert summary["counts"]["corrected"] == 7
    assert [e["file"] for e in summary["errors"]] == ["bad.mod"]
    assert "bad.mod:2" in summary["errors"][0]["message"]
    r = _filter(client, rid, _files("cell_a.mod", extra=BAD))
    assert r.status_code == 200 and r.headers["content-type"] == "application/zip"
    with zipfile.ZipFile(io.BytesIO(r.content)) as zf:
        assert set(zf.namelist()) == {"cell_a.mod", "filter-summary.json"}
    # every file bad: a 422 naming each
    r = _filter(client, rid, [("files", (BAD[0], BAD[1], "text/plain"))])
    assert r.status_code == 422 and "bad.mod:2" in r.text
