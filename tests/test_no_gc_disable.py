"""No library code turns the cyclic garbage collector off: the service runs requests
concurrently, and a request that disables it disables it for every other (issue 34, item 7).
Benchmarks may measure what it would buy (bench/filter_speed.py); the library never does it."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LIBRARY = ("calib", "daemon", "drivers", "simulator")


def _disables(tree: ast.AST) -> list[int]:
    """Lines calling ``gc.disable()`` or importing ``disable`` from ``gc``."""
    out = []
    for node in ast.walk(tree):
        call = (
            isinstance(node, ast.Attribute)
            and node.attr == "disable"
            and isinstance(node.value, ast.Name)
            and node.value.id == "gc"
        )
        imported = (
            isinstance(node, ast.ImportFrom)
            and node.module == "gc"
            and any(a.name == "disable" for a in node.names)
        )
        if call or imported:
            out.append(node.lineno)
    return out


def test_the_finder_finds_both_forms() -> None:
    assert _disables(ast.parse("import gc\ngc.disable()\n")) == [2]
    assert _disables(ast.parse("from gc import disable\n")) == [1]
    assert _disables(ast.parse("import gc\ngc.freeze()\ngc.enable()\n")) == []


def test_no_library_module_disables_the_garbage_collector() -> None:
    found = {
        str(p.relative_to(ROOT)): lines
        for folder in LIBRARY
        for p in sorted((ROOT / folder).rglob("*.py"))
        if (lines := _disables(ast.parse(p.read_text(encoding="utf-8"))))
    }
    assert found == {}
