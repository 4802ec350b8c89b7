"""Issue 33 item 1: nothing but the typed result (calib/result.py) reads result.json's dict.

An AST scan of the project's code (calib, daemon, bench) finds a read of one of the result's
top-level keys (:data:`calib.result.RESULT_KEYS`) on an object that holds a result: a name
such as ``result``/``res`` (:data:`RESULT_NAMES`), a row's ``["result"]``, or an
``IdentifyResult``'s ``.to_json()``. A read is ``x["key"]``, ``x.get("key")``, ``x.pop("key")``,
``x.setdefault("key")``, ``"key" in x`` and the HTML report's ``get_map(x, "key")``/
``get_list(x, "key")``. ``python tests/test_result_reads.py [ROOT]`` prints every read and
their count.
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

from calib.result import RESULT_KEYS

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("calib", "daemon", "bench")
#: The typed result itself, and the producer (it writes the dict; reads of its own locals).
HOMES = {"calib/result.py", "calib/result_fields.py", "calib/identify/result_json.py"}
#: Names the code gives an object holding a parsed result.json.
RESULT_NAMES = {"result", "res", "calibration", "current", "new", "stored"}
#: Modules allowed to read the dict, with the reason.
ALLOWED = {
    "bench/convention_identity.py": "compares whole documents key by key, the time left out",
}
READ_METHODS = {"get", "pop", "setdefault"}
READ_HELPERS = {"get_map", "get_list"}


def _holds_result(node: ast.expr) -> bool:
    """``node`` is an object holding a result: ``result``, ``x.result``, ``x["result"]``,
    ``x.to_json()``."""
    if isinstance(node, ast.Name):
        return node.id in RESULT_NAMES
    if isinstance(node, ast.Attribute):
        return node.attr in RESULT_NAMES
    if isinstance(node, ast.Subscript):
        key = node.slice
        return isinstance(key, ast.Constant) and key.value == "result"
    if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute):
        return node.func.attr == "to_json" and _holds_result(node.func.value)
    return False


def _key(node: ast.expr | None) -> str | None:
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return node.value if node.value in RESULT_KEYS else None
    return None


def reads(tree: ast.AST) -> list[tuple[int, str]]:
    """Every read of a result key on a result-holding object: ``(line, key)``."""
    out: list[tuple[int, str]] = []
    for node in ast.walk(tree):
        key: str | None = None
        if isinstance(node, ast.Subscript) and isinstance(node.ctx, ast.Load):
            key = _key(node.slice) if _holds_result(node.value) else None
        elif isinstance(node, ast.Call) and node.args:
            func = node.func
            if isinstance(func, ast.Attribute) and func.attr in READ_METHODS:
                key = _key(node.args[0]) if _holds_result(func.value) else None
            elif isinstance(func, ast.Name) and func.id in READ_HELPERS and len(node.args) > 1:
                key = _key(node.args[1]) if _holds_result(node.args[0]) else None
        elif (
            isinstance(node, ast.Compare)
            and isinstance(node.ops[0], ast.In | ast.NotIn)
            and _holds_result(node.comparators[0])
        ):
            key = _key(node.left)
        if key is not None:
            out.append((node.lineno, key))
    return out


def scan(root: Path = ROOT) -> list[str]:
    """``path:line: key`` of every read outside the typed result, in path order."""
    found = []
    for pkg in PACKAGES:
        for path in sorted((root / pkg).rglob("*.py")):
            rel = str(path.relative_to(root))
            if rel in HOMES or rel in ALLOWED:
                continue
            tree = ast.parse(path.read_text(encoding="utf-8"), filename=rel)
            found += [f"{rel}:{line}: {key}" for line, key in sorted(reads(tree))]
    return found


def test_no_module_reads_the_result_dict() -> None:
    found = scan()
    assert found == [], "read result.json through calib.result.CalibrationResult:\n" + "\n".join(
        found
    )


def test_the_scan_finds_each_kind_of_read() -> None:
    code = """
result["dh"]
res.get("anchor_id", "A")
row["result"]["metrics"]
self.result.pop("notes")
fit.to_json()  # not a result name: not a read
res.to_json()["prior"]
"drift" in result
get_map(result, "split")
result["unknown_key"]
data["dh"]
result["dh"] = []
"""
    found = reads(ast.parse(code))
    assert found == [
        (2, "dh"),
        (3, "anchor_id"),
        (4, "metrics"),
        (5, "notes"),
        (7, "prior"),
        (8, "drift"),
        (9, "split"),
    ]


if __name__ == "__main__":
    hits = scan(Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT)
    print("\n".join(hits))
    print(f"{len(hits)} reads in {len({h.split(':')[0] for h in hits})} modules")
