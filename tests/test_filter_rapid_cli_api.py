"""A RAPID module with an absurd number or cut short, through the CLI (exit 2, the file and
line named, no traceback) and the service (422 naming them), issue 31 items 6 and 7."""

# ruff: noqa: F811  (fixtures imported from other test modules, then named as arguments)

from __future__ import annotations

from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from test_api_apply import calibrated, cell  # noqa: F401
from test_api_filter import API, client  # noqa: F401
from test_filter_cli import _run, setup  # noqa: F401
from test_service import AUTH

from calib.filter.run import EXIT_BAD_INPUT

NO_AXES = "[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]"
BAD = {
    "overflow.mod": (
        "MODULE Big\n    PROC main()\n        MoveL [[500,0,800],[0,0,1,0],[0,0,9E+999,0],"
        f"{NO_AXES}],v100,fine,tool0;\n    ENDPROC\nENDMODULE\n",
        "overflow.mod:3: number 9E+999 is out of range",
    ),
    "digits.mod": (
        f"MODULE Long\n    PROC main()\n        MoveL [[{'7' * 5000},0,800],[0,0,1,0],[0,0,0,0],"
        f"{NO_AXES}],v100,fine,tool0;\n    ENDPROC\nENDMODULE\n",
        "digits.mod:3: number 777777777777…(5000 characters) is out of range",
    ),
    "cut.mod": (
        "MODULE Cut\n    PROC main()\n        MoveL [[500,0,800],[0,0,1,0],[0,0,0,0],[9E+09,",
        "cut.mod:3: PROC main (line 2) has no ENDPROC: the module is cut short",
    ),
}


@pytest.mark.parametrize("name", sorted(BAD))
def test_the_cli_exits_2_naming_file_and_line(
    setup: dict[str, Path], tmp_path: Path, name: str
) -> None:
    text, message = BAD[name]
    bad = tmp_path / name
    bad.write_text(text)
    out = tmp_path / "out"
    r = _run(setup["result"], bad, "--robot", setup["robot"], "--out", out)
    assert r.exit_code == EXIT_BAD_INPUT, r.output
    assert message in " ".join(r.output.split()), r.output
    assert "Traceback" not in r.output and not (out / name).exists()


@pytest.mark.parametrize("name", sorted(BAD))
def test_the_service_answers_422_naming_file_and_line(
    client: TestClient, calibrated: dict[str, int], name: str
) -> None:
    text, message = BAD[name]
    files = [("files", (name, text.encode(), "application/octet-stream"))]
    r = client.post(f"{API}/robots/{calibrated['robot_id']}/filter", files=files, headers=AUTH)
    assert r.status_code == 422, r.text
    assert message in " ".join(e["msg"] for e in r.json()["detail"]), r.text
