"""Issue 33 item 3: each of these facts has one home in the packages; an AST scan finds the
literals that escape it (a number or string constant equal to the fact, outside its home)."""

from __future__ import annotations

import ast
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
}


def _constants(path: Path) -> list[tuple[object, int]]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    out: list[tuple[object, int]] = []
    for node in ast.walk(tree):
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
