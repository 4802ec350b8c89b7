"""Robot programs (``calib.programs``, ``cablecal program``): a 40-pose plan written in every
format and read back gives the same 40 poses in order to 0.001 deg; compensated targets too;
bad targets, options and program texts give errors naming the row, joint or line."""

from __future__ import annotations

import csv
import re
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from calib.models import builtin_model
from calib.planning import CSV_COLUMNS
from calib.programs import PROGRAM_FORMATS, dwell_s_for_settle
from calib.programs.common import ProgramError
from calib.programs.registry import detect_format, parse_program
from calib.tcp import workspace_sample_deg
from daemon.cli import app
from daemon.sampler.config import SamplerConfig

MODEL = builtin_model("hsr-jr680")
LIMITS = MODEL.limits_deg()


def plan_csv(path: Path, n: int = 40, seed: int = 7) -> np.ndarray:
    """A plan CSV in ``cablecal plan``'s layout with ``n`` poses within the limits (4
    decimals, as the planner writes them); returns the poses (n, 6) [deg]."""
    q = np.round(workspace_sample_deg(MODEL, n, seed), 4)
    with path.open("w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(CSV_COLUMNS)
        for i, row in enumerate(q):
            w.writerow([i + 1, *row, "A", 1000.0, 1400.0, 300.0, 200.0])
    return q


def run(args: list[str], env: dict[str, str] | None = None) -> tuple[int, str]:
    res = CliRunner().invoke(app, ["program", *args], env={"COLUMNS": "80", **(env or {})})
    return res.exit_code, res.output


@pytest.mark.parametrize("fmt", PROGRAM_FORMATS)
def test_plan_to_program_and_back_gives_the_40_poses_in_order(tmp_path: Path, fmt: str) -> None:
    q = plan_csv(tmp_path / "plan.csv")
    out = tmp_path / "CAL_PLAN.prog"
    code, text = run(
        [
            str(tmp_path / "plan.csv"),
            "--format",
            fmt,
            "--out",
            str(out),
            "--speed-pct",
            "30",
            "--dwell-s",
            "2.5",
        ]
    )
    assert code == 0, text
    assert "40 targets" in text and all(len(line) <= 80 for line in text.splitlines())
    body = out.read_text(encoding="utf-8")
    assert detect_format(body) == fmt
    back = parse_program(fmt, body)
    got = np.array(back.joints_deg)
    assert got.shape == (40, 6)
    np.testing.assert_allclose(got, q, atol=0.0005 + 1e-9)  # written to 0.001 deg, in order
    assert (back.name.upper(), back.speed_pct, back.dwell_s) == ("CAL_PLAN", 30.0, 2.5)
    # The header comment names the targets, the robot and the date.
    head = " ".join(back.comments)
    assert "plan.csv" in head and "hsr-jr680" in head
    assert re.search(r"\d{4}-\d\d-\d\d \d\d:\d\d UTC", head)
    # One fine stop and one dwell per target.
    stops = {
        "rapid": r"MoveAbsJ .*, fine, tool0;",
        "urscript": r"movej\(.*r=0\)",
        "krl": r"^PTP \{A1 [^}]*\}$",
        "fanuc-ls": r"J P\[\d+\] 30% FINE",
    }
    waits = {
        "rapid": r"WaitTime\\InPos, 2.5;",
        "urscript": r"sleep\(2.5\)",
        "krl": r"^WAIT SEC 2.5$",
        "fanuc-ls": r"WAIT\s+2.50\(sec\)",
    }
    assert len(re.findall(stops[fmt], body, re.MULTILINE)) == 40
    assert len(re.findall(waits[fmt], body, re.MULTILINE)) == 40


def test_compensated_targets_become_a_program_and_flagged_ones_are_refused(tmp_path: Path) -> None:
    q = np.round(workspace_sample_deg(MODEL, 5, 3), 6)
    header = [
        "index",
        *(f"q{j}_nominal" for j in range(1, 7)),
        "q1",
        "q2",
        "q3",
        "q4",
        "q5",
        "q6",
        "x",
        "y",
        "z",
        "residual_mm",
        "flags",
    ]
    rows = [[i, *(q[i] - 0.01), *q[i], 1.0, 2.0, 3.0, 0.0001, ""] for i in range(5)]
    path = tmp_path / "corrected.csv"
    with path.open("w", newline="", encoding="utf-8") as fh:
        csv.writer(fh).writerows([header, *rows])
    out = tmp_path / "corr.src"
    code, text = run([str(path), "--format", "krl", "--out", str(out)])
    assert code == 0, text
    back = parse_program("krl", out.read_text())
    np.testing.assert_allclose(np.array(back.joints_deg), q, atol=0.0005 + 1e-9)  # corrected
    rows[3][-1] = "not_converged;outside_limits"
    with path.open("w", newline="", encoding="utf-8") as fh:
        csv.writer(fh).writerows([header, *rows])
    out.unlink()
    code, text = run([str(path), "--format", "krl", "--out", str(out)])
    flat = " ".join(text.split())
    assert code == 2 and "row 5: the target is flagged (not_converged, outside_limits)" in flat
    assert not out.exists()


def test_default_dwell_follows_the_samplers_settle_window(tmp_path: Path) -> None:
    plan_csv(tmp_path / "plan.csv", n=3)
    out = tmp_path / "p.script"
    default = SamplerConfig.model_fields["settle_s"].default
    for env, settle in (({}, default), ({"CABLECAL_SAMPLER__SETTLE_S": "1.2"}, 1.2)):
        code, text = run(
            [str(tmp_path / "plan.csv"), "--format", "urscript", "--out", str(out)], env
        )
        assert code == 0, text
        dwell = parse_program("urscript", out.read_text()).dwell_s
        assert dwell == dwell_s_for_settle(settle) and dwell > 2 * settle
    assert dwell_s_for_settle(0.5) == 2.0 and dwell_s_for_settle(0.3) == 1.4


OK_ROW = [0, -30, 200, 0, 20, 0]
BAD_TARGETS = [
    (
        [[0, -30, 301, 0, 20, 0]],
        [],
        r"row 2, q3: 301.000 deg is outside the joint limits \[60, 300\] deg",
    ),
    ([OK_ROW, [0, -30, 200, 0, "x", 0]], [], r"row 3, column 'q5': not a number: 'x'"),
    ([[0, -30, 200, 0, 20, "nan"]], [], r"row 2, column 'q6': not finite"),
    ([OK_ROW], ["--speed-pct", "150"], r"speed_pct: must be within 1..100 %"),
    ([OK_ROW], ["--name", "9lives"], r"'9lives' is not a valid RAPID program name"),
    ([OK_ROW], ["--name", "a" * 33], r"has 33 characters; RAPID allows 32"),
    ([], [], r"no targets after the header"),
]


@pytest.mark.parametrize(("rows", "args", "message"), BAD_TARGETS)
def test_bad_targets_and_options_name_the_row_and_joint(
    tmp_path: Path, rows: list[list[object]], args: list[str], message: str
) -> None:
    path = tmp_path / "t.csv"
    with path.open("w", newline="", encoding="utf-8") as fh:
        csv.writer(fh).writerows([["q1", "q2", "q3", "q4", "q5", "q6"], *rows])
    out = tmp_path / "t.mod"
    code, text = run([str(path), "--format", "rapid", "--out", str(out), *args])
    assert code == 2, text
    assert re.search(message, " ".join(text.split())), text
    assert not out.exists()  # nothing written


JT = "[[0,0,0,0,0,0],[9E9,9E9,9E9,9E9,9E9,9E9]]"
BAD_PROGRAMS = [
    (
        "krl",
        "DEF p( )\nPTP {A1 0,A2 0,A3 90,A4 0,A5 0,A6 0} C_PTP\nEND\n",
        r"line 2: C_PTP approximates",
    ),
    ("krl", "DEF p( )\nPTP {A1 0,A2 0,A3 90,A4 0,A5 0}\nEND\n", r"line 2: PTP without A6"),
    ("krl", "DEF p( )\nPTP {A1 0,A2 0,A3 90,A4 0,A5 0,A6 0}\n", r"missing END"),
    (
        "urscript",
        "def p():\n  movej([0,0,0,0,0,0], a=1, v=1, r=0.05)\nend\n",
        r"line 2: a blended movej",
    ),
    ("urscript", "def p():\n  movel(p[0,0,0,0,0,0])\nend\n", r"line 2: unknown statement"),
    (
        "rapid",
        "MODULE m\nPROC main()\nMoveAbsJ jt9\\NoEOffs, v100, fine, tool0;\nENDPROC\nENDMODULE\n",
        r"line 3: MoveAbsJ to an undeclared jointtarget",
    ),
    (
        "rapid",
        f"MODULE m\nCONST speeddata v:=[1,1,1,1];\nPROC main()\nMoveAbsJ {JT}, v, z10, "
        "tool0;\nENDPROC\nENDMODULE\n",
        r"line 4: expected MoveAbsJ target, speed, fine",
    ),
    ("fanuc-ls", "/PROG A\n/MN\n 1:J P[1] 50% CNT100 ;\n/POS\n/END\n", r"line 3: CNT100 blends"),
    (
        "fanuc-ls",
        "/PROG A\n/MN\n 1:J P[2] 50% FINE ;\n/POS\n/END\n",
        r"line 3: P\[2\] is not defined",
    ),
    ("fanuc-ls", "/PROG A\n/MN\n/END\n", r"expected /PROG, /MN, /POS, /END"),
]


@pytest.mark.parametrize(("fmt", "text", "message"), BAD_PROGRAMS)
def test_parsers_refuse_what_would_not_stop(fmt: str, text: str, message: str) -> None:
    with pytest.raises(ProgramError, match=message):
        parse_program(fmt, text)


def test_names_valid_for_each_controller(tmp_path: Path) -> None:
    plan_csv(tmp_path / "plan.csv", n=2)
    out = tmp_path / "2nd-plan.LS"
    code, text = run([str(tmp_path / "plan.csv"), "--format", "fanuc-ls", "--out", str(out)])
    assert code == 0, text
    assert out.read_text().startswith("/PROG  P2ND_PLAN")  # upper case, a letter first
    assert "rename the file P2ND_PLAN.LS" in " ".join(text.split())


def test_a_plan_for_two_anchors_gives_one_program_per_anchor(tmp_path: Path) -> None:
    q = plan_csv(tmp_path / "plan.csv", n=6)
    rows = (tmp_path / "plan.csv").read_text().splitlines()
    rows[4:] = [r.replace(",A,", ",B,") for r in rows[4:]]  # poses 4..6 at anchor B
    (tmp_path / "plan.csv").write_text("\n".join(rows) + "\n")
    out = tmp_path / "two.src"
    code, text = run([str(tmp_path / "plan.csv"), "--format", "krl", "--out", str(out)])
    assert code == 2 and "--anchor: " in text and "anchors A, B" in " ".join(text.split())
    assert not out.exists()
    code, text = run(
        [str(tmp_path / "plan.csv"), "--format", "krl", "--out", str(out), "--anchor", "B"]
    )
    assert code == 0, text
    back = parse_program("krl", out.read_text())
    np.testing.assert_allclose(np.array(back.joints_deg), q[3:], atol=0.0005 + 1e-9)
    assert "sensor at anchor B" in " ".join(back.comments)
    code, text = run(
        [str(tmp_path / "plan.csv"), "--format", "krl", "--out", str(out), "--anchor", "C"]
    )
    assert code == 2 and "'C' is not in" in text
