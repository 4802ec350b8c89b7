"""Issue 28, item 4: every file cablecal writes escapes what it carries. A name is the only
text a user puts into a model file or a robot program; each format has one helper
(:func:`calib.export.xml_text` / :func:`calib.export.xml_comment` for URDF,
:func:`calib.export.toml_comment` for TOML comments, :func:`calib.programs.common.clean_comment`
and :class:`calib.programs.common.NameRule` for the four program formats), and the files are
checked here the way a reader meets them: parsed."""

from __future__ import annotations

import csv
import io
import tomllib
import xml.etree.ElementTree as ET
from dataclasses import replace
from pathlib import Path

import pytest

from calib.export import model_to_toml, model_to_urdf
from calib.models import builtin_model, parse_model_text
from calib.programs.common import JointProgram, NameRule, clean_comment
from calib.programs.formats import PROGRAM_FORMATS
from calib.programs.registry import name_rule, parse_program, write_program

EVIL_NAMES = [
    'evil --><link name="injected"/><!-- x',
    "ends with a dash -",
    "--",
    "bell\x07 esc\x1b[2J nul\x00 del\x7f c1\x85 nl\n cr\r tab\t ls\u2028 end",
    "quote\" apos' amp& lt< gt> ]]>",
    "\ufffe\uffff",
]


@pytest.mark.parametrize("name", EVIL_NAMES)
def test_urdf_stays_valid_xml_whatever_the_model_name(name: str) -> None:
    """The model name went into an XML comment as it was: ``-->`` ended the comment and the
    rest became elements. Now the URDF parses, has exactly its own links and joints, the
    comment is one comment, and the robot's name attribute carries the name (characters XML
    cannot hold replaced)."""
    model = replace(builtin_model("hsr-jr680"), name=name)
    text = model_to_urdf(model)
    root = ET.fromstring(text.encode())  # raises on invalid XML
    links = [e.get("name") for e in root.iter("link")]
    assert "injected" not in links and len(links) == 9
    assert len(list(root.iter("joint"))) == 8
    assert text.count("<!--") == 1 and text.count("-->") == 1
    comment = text.split("<!--", 1)[1].split("-->", 1)[0]
    assert "--" not in comment and "\n" not in comment
    expected = "".join(
        "\ufffd" if (ord(c) < 32 and c not in "\t\n\r") or c in "\ufffe\uffff" else c for c in name
    )
    # XML normalises a CR LF or a lone CR in an attribute only when not escaped: it is.
    assert root.get("name") == expected


@pytest.mark.parametrize("name", EVIL_NAMES)
def test_toml_model_file_comments_stay_comments(name: str) -> None:
    """A comment line carries no control character (TOML refuses them) and no line break:
    the file parses and its model is the model."""
    model = replace(builtin_model("hsr-jr680"), name=name.replace("\x00", ""))
    text = model_to_toml(model, comments=[f"Calibrated model of {name!r}", name])
    data = tomllib.loads(text)
    assert data["name"] == model.name
    lines = text.split("\n")
    n_comments = 1 + len(model.name.splitlines())
    assert all(line.startswith("# ") for line in lines[:n_comments]), lines[:n_comments]
    assert not lines[n_comments].startswith("#")
    assert parse_model_text(text, "toml").to_dict() == model.to_dict()


@pytest.mark.parametrize("fmt", PROGRAM_FORMATS)
def test_program_comments_and_names_carry_no_terminator(fmt: str) -> None:
    """A comment from a name (robot, campaign, anchor) cannot break its line or end its
    comment early in RAPID (``!``), URScript (``#``), KRL (``;``) or Fanuc LS (``! … ;``):
    the program parses back with the same targets and every comment line is one comment;
    a program name from any text follows the controller's rule."""
    joints = ((0.0, -60.0, 200.0, -170.0, 40.0, 60.0), (1.0, -61.0, 201.0, -171.0, 41.0, 61.0))
    comments = (*(f"robot {n}" for n in EVIL_NAMES), "a;b\nPTP {A1 0}\r\nMoveJ", "*/ }")
    rule = name_rule(fmt)
    name = rule.from_text('x"; DEF evil()\n')
    assert rule.check(name) == name
    program = JointProgram(name, joints, speed_pct=10, dwell_s=1, comments=comments)
    text = write_program(fmt, program)
    back = parse_program(fmt, text)
    assert back.joints_deg == joints
    assert back.name.upper() == name.upper()
    assert len(back.comments) >= len(comments)  # each one a comment still, none split off
    for line in text.splitlines():
        assert line.isascii() and all(c == "\t" or 32 <= ord(c) < 127 for c in line), repr(line)


def test_clean_comment_and_name_rule_are_the_helpers() -> None:
    assert clean_comment("a;b\nc\x1b!") == "a_b_c_!"
    assert "\n" not in clean_comment("x\r\ny") and ";" not in clean_comment("x;y")
    assert NameRule("KRL", 24).from_text("1 evil;\nDEF") == "P1_evil__DEF"


def test_the_plan_csv_neutralises_formula_anchors_and_reads_them_back(
    tmp_path: Path,
) -> None:
    """An anchor id ``=cmd|' /C calc'!A0`` came back in ``GET /campaigns/{id}/plan?format=csv``
    as it was; the plan CSV is now written by the samples export's guard
    (:func:`calib.csvtext.write_csv`): the cell gets one ``'``, numbers stay numbers, and a
    program download for that anchor still finds it (the reader drops the ``'``)."""
    from fastapi.testclient import TestClient
    from test_service import AUTH, TOKEN, FakeSampler, _settings

    from calib.csvtext import restore_cell
    from daemon.api.main import create_app

    evil = "=cmd|' /C calc'!A0"
    app = create_app(_settings(tmp_path), TOKEN, sampler_factory=FakeSampler)
    with TestClient(app) as client:
        cid = client.post("/api/v1/campaigns", json={"name": "p"}, headers=AUTH).json()["id"]
        body = {
            "anchors_mm": [[1430.0, 330.0, 230.0]],
            "anchor_ids": [evil],
            "n": 8,
            "candidates": 200,
            "seed": 2,
        }
        r = client.post(f"/api/v1/campaigns/{cid}/plan", json=body, headers=AUTH)
        assert r.status_code == 201, r.text
        url = f"/api/v1/campaigns/{cid}/plan"
        text = client.get(url, params={"format": "csv"}, headers=AUTH).text
        rows = list(csv.DictReader(io.StringIO(text)))
        assert len(rows) == 8 and {r["anchor"] for r in rows} == {"'" + evil}
        for row in rows:  # numbers are never prefixed: a minus sign stays a number
            assert all(not row[f"q{j}"].startswith("'") for j in range(1, 7))
            float(row["q2"])
        assert {restore_cell(r["anchor"]) for r in rows} == {evil}
        r = client.get(url, params={"format": "krl", "anchor": evil}, headers=AUTH)
        assert r.status_code == 200, r.text
        assert len(parse_program("krl", r.text).joints_deg) == len(rows)
