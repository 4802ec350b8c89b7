"""Issue 33 item 3: each of these facts has one home in the packages; an AST scan finds the
literals that escape it (a number or string constant equal to the fact, outside its home)."""

from __future__ import annotations

import ast
import functools
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("calib", "daemon", "drivers", "simulator")

#: fact value → (its home, why it is a fact, other modules allowed to hold it with the reason)
FACTS: dict[object, tuple[str, str, dict[str, str]]] = {
    8080: ("daemon/defaults.py", "the API's default port", {}),
    "daemon_stopped": ("daemon/process/lifecycle.py", "the clean-stop event", {}),
    -170.0: (
        "calib/models.py",
        "default joint limits and the pose clip",
        {},
    ),
    170.0: ("calib/models.py", "default joint limits and the pose clip", {}),
    "A": (
        "calib/sample_fields.py",
        "the default anchor id",
        {
            "calib/programs/krl/data.py": "KRL's A angle of a Cartesian point, not an anchor",
        },
    ),
    # The job states only one meaning writes ("running" and "failed" are check states and
    # capture outcomes too, so a scan cannot tell them apart).
    "queued": ("daemon/store/rows.py", "a job state (JobState)", {}),
    "succeeded": ("daemon/store/rows.py", "a job state (JobState)", {}),
    "cancelled": ("daemon/store/rows.py", "a job state (JobState)", {}),
    "0.1.0": ("daemon/__init__.py", "the release (pyproject.toml reads it)", {}),
    "hold_check_not_held": ("daemon/monitors/holdcheck.py", "the event of a robot not held", {}),
}

#: type alias → (its home, other modules allowed to define it with the reason)
TYPE_ALIASES: dict[str, tuple[str, dict[str, str]]] = {
    "FloatArray": ("calib/kinematics.py", {}),
    "Joints": (
        "calib/sample_fields.py",
        {
            "calib/programs/common.py": "calib/programs is the program-filter issue's code; "
            "it imports Joints from calib.sample_fields when that issue rewrites it",
        },
    ),
}


@functools.cache
def _constants(path: Path) -> list[tuple[object, int]]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    out: list[tuple[object, int]] = []
    # The literal text of an f-string (the "A" of f"A{j}", KRL's axis names) is not a value.
    in_fstring = {
        id(part)
        for node in ast.walk(tree)
        if isinstance(node, ast.JoinedStr)
        for part in node.values
    }
    for node in ast.walk(tree):
        if id(node) in in_fstring:
            continue
        if isinstance(node, ast.Constant) and not isinstance(node.value, bool):
            out.append((node.value, node.lineno))
        elif (  # -170.0 is UnaryOp(USub, 170.0): counted as 170.0 above
            isinstance(node, ast.UnaryOp)
            and isinstance(node.op, ast.USub)
            and isinstance(node.operand, ast.Constant)
            and isinstance(node.operand.value, int | float)
        ):
            out.append((-node.operand.value, node.lineno))
    return out


@pytest.mark.parametrize("fact", list(FACTS), ids=str)
def test_a_fact_lives_in_its_home_only(fact: object) -> None:
    home, what, allowed = FACTS[fact]
    assert (ROOT / home).exists(), home
    found = []
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            rel = str(path.relative_to(ROOT))
            if rel == home or rel in allowed:
                continue
            for value, line in _constants(path):
                if type(value) is type(fact) and value == fact:
                    found.append(f"{rel}:{line}")
    assert found == [], f"{what} ({fact!r}) written outside {home}: {found}"


@functools.cache
def _defined_names(path: Path) -> list[tuple[str, int]]:
    """Module-level names bound by an assignment (``X = ...`` or ``X: T = ...``)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    out: list[tuple[str, int]] = []
    for node in tree.body:
        if isinstance(node, ast.Assign):
            out += [(t.id, node.lineno) for t in node.targets if isinstance(t, ast.Name)]
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            out.append((node.target.id, node.lineno))
    return out


@pytest.mark.parametrize("alias", list(TYPE_ALIASES))
def test_a_type_alias_is_defined_in_its_home_only(alias: str) -> None:
    home, allowed = TYPE_ALIASES[alias]
    assert (alias,) in [(n,) for n, _ in _defined_names(ROOT / home)], home
    found = []
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            rel = str(path.relative_to(ROOT))
            if rel == home or rel in allowed:
                continue
            found += [f"{rel}:{line}" for name, line in _defined_names(path) if name == alias]
    assert found == [], f"{alias} defined outside {home}: {found}"


def test_the_scan_finds_an_escaped_literal(tmp_path: Path) -> None:
    """The scans can fail: a module writing a fact, or defining an alias, is found."""
    bad = tmp_path / "bad.py"
    bad.write_text('ANCHOR = "A"\nLIMIT = -170.0\nJoints = tuple[float, ...]\n', encoding="utf-8")
    assert ("A", 1) in _constants(bad) and (-170.0, 2) in _constants(bad)
    assert ("Joints", 3) in _defined_names(bad)
