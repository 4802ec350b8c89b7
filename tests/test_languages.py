"""The controller languages' registry (calib.programs.formats.LANGUAGES): the one home of each
language's name, extensions, line ending and help; the CLI, the API, the page and the filter's
dialects read it, and no other module keeps a list of its own."""

from __future__ import annotations

import ast
import importlib
import re
from collections.abc import Iterator
from pathlib import Path

import pytest
from fastapi.testclient import TestClient
from test_service import AUTH, TOKEN, FakeSampler
from typer.testing import CliRunner

from calib.programs.dialects import dialects
from calib.programs.formats import LANGUAGES, PROGRAM_FORMATS, SUFFIX, filter_files_help
from calib.programs.registry import parse_program
from daemon.api.main import create_app
from daemon.config import Settings

ROOT = Path(__file__).resolve().parents[1]
API = "/api/v1"


@pytest.fixture(scope="module")
def client(tmp_path_factory: pytest.TempPathFactory) -> Iterator[TestClient]:
    settings = Settings(state_dir=tmp_path_factory.mktemp("languages"), api_token=TOKEN)
    with TestClient(create_app(settings, TOKEN, sampler_factory=FakeSampler)) as c:
        yield c


def test_the_dialects_and_writers_are_the_registrys() -> None:
    assert tuple(d.name for d in dialects()) == PROGRAM_FORMATS
    for d in dialects():
        assert d.extensions == LANGUAGES[d.name].extensions
        assert all(e == e.lower() and e.startswith(".") for e in d.extensions)
    for lang in LANGUAGES.values():
        writer = importlib.import_module(lang.program_module)
        assert callable(writer.write) and callable(writer.parse)
        assert lang.suffix.lower() in lang.extensions and SUFFIX[lang.name] == lang.suffix
    assert LANGUAGES["fanuc-ls"].newline == "\r\n"
    assert {lang.newline for n, lang in LANGUAGES.items() if n != "fanuc-ls"} == {"\n"}


def _literals(path: Path) -> set[str]:
    """The registry's file extensions written as whole string literals in ``path`` (Python:
    string constants, docstrings and messages aside; the page: quoted)."""
    known = {e for lang in LANGUAGES.values() for e in (*lang.extensions, lang.suffix)}
    text = path.read_text(encoding="utf-8")
    if path.suffix == ".py":
        return {
            n.value
            for n in ast.walk(ast.parse(text))
            if isinstance(n, ast.Constant) and isinstance(n.value, str) and n.value in known
        }
    return {e for e in known if re.search(r"[\"'`]" + re.escape(e) + r"[\"'`,]", text)}


def test_no_other_module_keeps_a_list_of_extensions() -> None:
    """Two or more of the languages' extensions in one module is a list of its own (one alone
    is a language's rule, as KRL's ``.dat`` holding data); the page names none (it reads
    ``GET /programs/languages``)."""
    home = ROOT / "calib" / "programs" / "formats.py"
    sources = [
        p
        for folder in ("calib", "daemon", "drivers", "simulator")
        for p in (ROOT / folder).rglob("*")
        if p.suffix in (".py", ".js", ".html") and p != home and "vendor" not in p.parts
    ]
    owners = {str(p.relative_to(ROOT)): found for p in sources if len(found := _literals(p)) > 1}
    assert owners == {}
    page = (ROOT / "daemon" / "web" / "index.html").read_text(encoding="utf-8")
    assert ".modx" not in page and ".urscript" not in page


def test_the_api_lists_the_languages_for_the_page(client: TestClient) -> None:
    assert client.get(f"{API}/programs/languages").status_code == 401
    r = client.get(f"{API}/programs/languages", headers=AUTH)
    assert r.status_code == 200, r.text
    body = r.json()
    assert [x["name"] for x in body["languages"]] == list(PROGRAM_FORMATS)
    fanuc = next(x for x in body["languages"] if x["name"] == "fanuc-ls")
    assert fanuc["line_ending"] == "CRLF" and fanuc["extensions"] == [".ls"]
    assert body["filter_files"] == filter_files_help()
    for lang in LANGUAGES.values():
        assert lang.files in body["filter_files"]


def test_fanuc_programs_are_crlf_from_the_cli_and_the_api_alike(tmp_path: Path) -> None:
    """``cablecal program --format fanuc-ls`` writes CRLF and nothing else; the same text as
    the registry's build (which the API's downloads serve); every other language LF."""
    from daemon.cli import app

    targets = tmp_path / "targets.csv"
    targets.write_text("q1,q2,q3,q4,q5,q6\n0,10,100,0,30,0\n5,15,110,0,35,0\n", encoding="utf-8")
    for fmt, lang in LANGUAGES.items():
        out = tmp_path / f"p{lang.suffix}"
        r = CliRunner().invoke(
            app, ["program", str(targets), "--format", fmt, "--out", str(out), "--name", "P1"]
        )
        assert r.exit_code == 0, r.output
        data = out.read_bytes()
        crlf = data.count(b"\r\n")
        if lang.newline == "\r\n":
            assert crlf == data.count(b"\n") > 5, fmt
        else:
            assert crlf == 0 and b"\r" not in data, fmt
        back = parse_program(fmt, data.decode("utf-8"))
        assert len(back.joints_deg) == 2


def test_a_program_is_told_from_a_csv_by_the_registrys_signatures() -> None:
    from calib.programs.common import JointProgram
    from calib.programs.registry import detect_format, write_program

    program = JointProgram("P1", ((0.0, 10.0, 100.0, 0.0, 30.0, 0.0),), 25.0, 1.0, ("made",))
    for fmt, lang in LANGUAGES.items():
        text = lang.with_newline(write_program(fmt, program))
        assert detect_format(text) == fmt
    assert detect_format("%%%\n  VERSION:1\n%%%\nMODULE M1\nENDMODULE\n") == "rapid"
    assert detect_format("pose,q1,q2,q3,q4,q5,q6\n1,0,0,0,0,0,0\n") == "csv"
    assert detect_format("0,10,100,0,30,0\n") == "csv"
