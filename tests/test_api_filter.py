"""POST /robots/{id}/filter in-process: 401, 404, 409, 413, 422 bounds, one file, a zip of
several, the summary (dry run); the filtered files differ from the uploads only in numbers."""

# ruff: noqa: F811  (the fixtures of test_api_apply are imported, then named as arguments)

from __future__ import annotations

import io
import json
import re
import zipfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient
from test_api_apply import _uncalibrated_robot, calibrated, cell  # noqa: F401
from test_service import AUTH, TOKEN, FakeSampler

from daemon.api.http.guard import MAX_FILTER_BYTES
from daemon.api.main import create_app
from daemon.api.routes.robots.program_filter import MAX_FILES
from daemon.config import Settings

API = "/api/v1"
FRAMES_BAD = b"[uframe.1]\nxyz_mm = [1, 2]\nwpr_deg = [0, 0, 0]\n"
FIXTURES = Path(__file__).parent / "fixtures" / "programs"
_NUMBER = re.compile(rb"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")


@pytest.fixture(scope="module")
def client(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TestClient]:
    tmp = tmp_path_factory.mktemp("filter")
    settings = Settings(state_dir=tmp, api_token=TOKEN)
    with TestClient(create_app(settings, TOKEN, sampler_factory=FakeSampler)) as c:
        yield c


def _files(*names: str) -> list[tuple[str, tuple[str, bytes, str]]]:
    return [("files", (n, (FIXTURES / n).read_bytes(), "application/octet-stream")) for n in names]


def test_filter_needs_the_token_a_robot_and_a_calibration(
    client: TestClient,
    calibrated: dict[str, int],
) -> None:
    rid = calibrated["robot_id"]
    r = client.post(f"{API}/robots/{rid}/filter", files=_files("cell_a.mod"))
    assert r.status_code == 401
    r = client.post(f"{API}/robots/999/filter", files=_files("cell_a.mod"), headers=AUTH)
    assert r.status_code == 404
    bare = _uncalibrated_robot(client)
    r = client.post(f"{API}/robots/{bare}/filter", files=_files("cell_a.mod"), headers=AUTH)
    assert r.status_code == 409 and "no current calibration" in r.json()["detail"]


def test_dry_run_returns_the_summary(client: TestClient, calibrated: dict[str, int]) -> None:
    r = client.post(
        f"{API}/robots/{calibrated['robot_id']}/filter",
        files=_files("cell_a.mod", "notes_e.mod"),
        params={"dry_run": "true"},
        headers=AUTH,
    )
    assert r.status_code == 200, r.text
    summary = r.json()
    rows = {t["name"]: t for t in summary["targets"]}
    assert set(rows) == {
        "pApproach",
        "pEdge",
        "pPath{1}",
        "pPath{2}",
        "pPath{3}",
        "jHome",
        "inline@32",
    }
    assert all(t["status"] == "corrected" for t in rows.values())
    assert all(t["shift_mm"] > 0.01 and t["sigma_at_tool_mm"] is not None for t in rows.values())
    assert summary["exit_code"] == 0 and summary["counts"]["corrected"] == 7
    assert {f["file"]: f["targets"] for f in summary["files"]} == {
        "cell_a.mod": 7,
        "notes_e.mod": 0,
    }


def test_one_file_comes_back_changed_only_in_numbers(
    client: TestClient,
    calibrated: dict[str, int],
) -> None:
    r = client.post(
        f"{API}/robots/{calibrated['robot_id']}/filter",
        files=_files("polyscope_c.script"),
        headers=AUTH,
    )
    assert r.status_code == 200, r.text
    assert 'filename="polyscope_c.script"' in r.headers["content-disposition"]
    assert json.loads(r.headers["x-filter-counts"])["corrected"] == 9
    original = (FIXTURES / "polyscope_c.script").read_bytes()
    assert r.content != original
    assert _NUMBER.sub(b"#", r.content) == _NUMBER.sub(b"#", original)


def test_a_fanuc_program_comes_back_crlf_as_it_went(
    client: TestClient,
    calibrated: dict[str, int],
) -> None:
    """Fanuc's .LS is CRLF (calib.programs.formats.LANGUAGES): the filter's download keeps
    every line end as the upload has it, none turned into LF."""
    original = (FIXTURES / "fanuc" / "GRIP_OPEN.LS").read_bytes()
    assert original.count(b"\r\n") == original.count(b"\n") > 5
    r = client.post(
        f"{API}/robots/{calibrated['robot_id']}/filter",
        files=[("files", ("GRIP_OPEN.LS", original, "application/octet-stream"))],
        headers=AUTH,
    )
    assert r.status_code == 200, r.text
    assert r.content.count(b"\r\n") == r.content.count(b"\n") == original.count(b"\n")
    assert _NUMBER.sub(b"#", r.content) == _NUMBER.sub(b"#", original)


def test_several_files_come_back_as_a_zip_with_the_summary(
    client: TestClient,
    calibrated: dict[str, int],
) -> None:
    names = ("station_b.prg", "tools_b.sys", "notes_e.mod", "plain_d.urscript")
    r = client.post(
        f"{API}/robots/{calibrated['robot_id']}/filter", files=_files(*names), headers=AUTH
    )
    assert r.status_code == 200, r.text
    assert r.headers["content-type"] == "application/zip"
    assert r.headers["x-filter-exit-code"] == "3"  # pB3, pB4, pB5 are left and named
    with zipfile.ZipFile(io.BytesIO(r.content)) as zf:
        got = {n: zf.read(n) for n in zf.namelist()}
    assert set(got) == {*names, "filter-summary.json"}
    for n in names:
        original = (FIXTURES / n).read_bytes()
        assert _NUMBER.sub(b"#", got[n]) == _NUMBER.sub(b"#", original), n
    assert got["notes_e.mod"] == (FIXTURES / "notes_e.mod").read_bytes()
    assert b"\r\n" in got["station_b.prg"] and "Schweiß".encode("latin-1") in got["station_b.prg"]
    left = {
        t["name"]: t["reason"]
        for t in json.loads(got["filter-summary.json"])["targets"]
        if t["status"] != "corrected"
    }
    assert set(left) == {"pB3", "pB4", "pB5"}


@pytest.mark.parametrize(
    ("files", "message"),
    [
        (
            [
                (
                    "files",
                    (
                        "bad.mod",
                        b"MODULE B\n  CONST robtarget p:=[[1,2],[1,0,0,0]];\nENDMODULE\n",
                        "text/plain",
                    ),
                )
            ],
            "bad.mod:2",
        ),
        ([("files", ("x.txt", b"hello", "text/plain"))], "x.txt: unknown program dialect"),
        (
            [("files", ("../up.mod", b"MODULE U\nENDMODULE\n", "text/plain"))],
            "must be a plain name",
        ),
        (
            [
                ("frames", ("f.toml", FRAMES_BAD, "text/plain")),
                ("files", ("notes_e.mod", b"MODULE N\nENDMODULE\n", "text/plain")),
            ],
            "xyz_mm: expected 3 finite numbers",
        ),
        ([("other", ("o.txt", b"x", "text/plain"))], "unknown part"),
        (
            [
                ("files", (f"f{k}.mod", b"MODULE N\nENDMODULE\n", "text/plain"))
                for k in range(MAX_FILES + 1)
            ],
            f"at most {MAX_FILES}",
        ),
    ],
)
def test_bad_uploads_are_a_422_naming_the_file(
    client: TestClient, calibrated: dict[str, int], files: list[Any], message: str
) -> None:
    r = client.post(f"{API}/robots/{calibrated['robot_id']}/filter", files=files, headers=AUTH)
    assert r.status_code == 422, r.text
    assert message in " ".join(e["msg"] for e in r.json()["detail"]), r.text


def test_not_multipart_and_too_large(client: TestClient, calibrated: dict[str, int]) -> None:
    rid = calibrated["robot_id"]
    r = client.post(
        f"{API}/robots/{rid}/filter",
        content=b"MODULE X\nENDMODULE\n",
        headers={**AUTH, "Content-Type": "text/plain"},
    )
    assert r.status_code == 422 and "multipart/form-data" in r.text
    big = [("files", ("big.mod", b"!" * (MAX_FILTER_BYTES + 10), "text/plain"))]
    r = client.post(f"{API}/robots/{rid}/filter", files=big, headers=AUTH)
    assert r.status_code == 413
