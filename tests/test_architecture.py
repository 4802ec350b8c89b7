"""docs/architecture.md's import rules, held by an AST scan of the project's sources.

Every ``import`` and ``from ... import`` counts, at module level and inside functions (a
function-level import is still a dependency; it only moves its cost). The rules are the ones
the doc states in its "Packages" section; a test fails naming the module and the import.
"""

from __future__ import annotations

import ast
import re
from collections.abc import Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("calib", "daemon", "drivers", "simulator")
DOC = ROOT / "docs" / "architecture.md"


def _doc_rules() -> tuple[dict[str, set[str]], dict[str, set[str]], dict[tuple[str, str], str]]:
    """The "Import rules" table of docs/architecture.md, read as the test's allowed lists.

    Returns the third-party modules each package may import (a package whose cell is in
    parentheses is not restricted), the project packages each may import, and (package,
    imported) → the subpackage that alone may import it ("(only `daemon/cli/`)")."""
    text = DOC.read_text(encoding="utf-8")
    section = text.split("## Import rules", 1)[1].split("\n## ", 1)[0]
    third: dict[str, set[str]] = {}
    project: dict[str, set[str]] = {}
    only: dict[tuple[str, str], str] = {}
    for line in section.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) != 3 or not cells[0].startswith("`"):
            continue
        pkg = cells[0].strip("`/")
        if not cells[1].startswith("("):
            # "pyserial (`serial`)": the module's name is the one in backticks
            third[pkg] = {
                (re.findall(r"`(\w+)`", item) or [item.strip()])[0] for item in cells[1].split(",")
            }
        project[pkg] = (
            set() if cells[2] == "none" else set(re.findall(r"`(\w+)`,?", cells[2].split("(")[0]))
        )
        for name in re.findall(r"`(\w+)` \(only `([\w/]+)/`\)", cells[2]):
            only[(pkg, name[0])] = name[1].replace("/", ".")
    return third, project, only


def _doc_number(pattern: str) -> int:
    """A number the doc's import-rules section states (the test's limits live in the doc)."""
    section = DOC.read_text(encoding="utf-8").split("## Import rules", 1)[1].split("\n## ", 1)[0]
    found = re.search(pattern, " ".join(section.split()))
    assert found, f"docs/architecture.md no longer states {pattern!r}"
    return int(found.group(1))


#: Third-party imports and project packages each package may make, as the doc's table says.
ALLOWED_THIRD_PARTY, ALLOWED_PROJECT, ONLY_FROM = _doc_rules()
#: Largest module in the four packages [lines]: past it a module owns several things.
MAX_MODULE_LINES = _doc_number(r"no module of the four packages is over (\d+) lines")
#: The daemon modules allowed to import numpy (the daemon holds I/O, time and state).
MAX_DAEMON_NUMPY_MODULES = _doc_number(r"at most (\d+) daemon modules import numpy")


def test_the_doc_table_is_read() -> None:
    """The parse of the doc's table is what the doc says (a doc reworded past the parser
    fails here rather than silently allowing everything)."""
    assert set(ALLOWED_PROJECT) == set(PACKAGES)
    assert ALLOWED_PROJECT["calib"] == set() and ALLOWED_PROJECT["drivers"] == set()
    assert {"numpy", "scipy"} <= ALLOWED_THIRD_PARTY["calib"]
    assert "serial" in ALLOWED_THIRD_PARTY["drivers"] and "daemon" not in ALLOWED_THIRD_PARTY
    assert ONLY_FROM == {("daemon", "simulator"): "daemon.cli"}
    assert MAX_MODULE_LINES == 500 and MAX_DAEMON_NUMPY_MODULES == 6


def _modules() -> dict[str, Path]:
    out: dict[str, Path] = {}
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            rel = path.relative_to(ROOT).with_suffix("")
            parts = list(rel.parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            out[".".join(parts)] = path
    return out


MODULES = _modules()


def _imports(name: str, path: Path) -> Iterator[tuple[str, int]]:
    """Yield (imported dotted name, line) for every import in the module, resolved to absolute."""
    is_pkg = path.name == "__init__.py"
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield alias.name, node.lineno
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = name.split(".")
                base = base if is_pkg else base[:-1]
                base = base[: len(base) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            for alias in node.names:
                # ``from pkg import sub`` imports the submodule when there is one.
                sub = f"{mod}.{alias.name}"
                yield (sub if sub in MODULES else mod), node.lineno


def _project_target(imported: str) -> str | None:
    """The most specific project module an import names, or None if it is not ours."""
    parts = imported.split(".")
    while parts:
        cand = ".".join(parts)
        if cand in MODULES:
            return cand
        parts.pop()
    return None


def _skip_type_checking_only() -> None:
    return None


def test_package_import_rules() -> None:
    stdlib = set(__import__("sys").stdlib_module_names)
    problems = []
    for name, path in MODULES.items():
        pkg = name.split(".")[0]
        for imported, line in _imports(name, path):
            top = imported.split(".")[0]
            where = f"{path.relative_to(ROOT)}:{line} imports {imported}"
            if top == pkg or top in stdlib or top == "__future__":
                continue
            if top in PACKAGES:
                only = ONLY_FROM.get((pkg, top))
                if top not in ALLOWED_PROJECT[pkg] or (
                    only is not None and not (name == only or name.startswith(only + "."))
                ):
                    problems.append(where)
            elif pkg in ALLOWED_THIRD_PARTY and top not in ALLOWED_THIRD_PARTY[pkg]:
                problems.append(where)
    assert not problems, "imports that docs/architecture.md forbids:\n" + "\n".join(problems)


def test_daemon_imports_no_scipy_and_little_numpy() -> None:
    scipy_users, numpy_users = [], []
    for name, path in MODULES.items():
        if not name.startswith("daemon"):
            continue
        tops = {imported.split(".")[0] for imported, _ in _imports(name, path)}
        if "scipy" in tops:
            scipy_users.append(name)
        if "numpy" in tops:
            numpy_users.append(name)
    assert not scipy_users, f"daemon modules importing scipy: {scipy_users}"
    assert len(numpy_users) <= MAX_DAEMON_NUMPY_MODULES, (
        f"{len(numpy_users)} daemon modules import numpy (at most {MAX_DAEMON_NUMPY_MODULES}): "
        f"{sorted(numpy_users)}"
    )


def test_no_module_over_the_line_limit() -> None:
    long = {
        str(path.relative_to(ROOT)): n
        for path in MODULES.values()
        if (n := len(path.read_text(encoding="utf-8").splitlines())) > MAX_MODULE_LINES
    }
    assert not long, f"modules over {MAX_MODULE_LINES} lines: {long}"


def _graph() -> dict[str, set[str]]:
    graph: dict[str, set[str]] = {name: set() for name in MODULES}
    for name, path in MODULES.items():
        for imported, _ in _imports(name, path):
            target = _project_target(imported)
            if target is not None and target != name:
                graph[name].add(target)
    return graph


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on_stack: set[str] = set()
    stack: list[str] = []
    out: list[list[str]] = []
    counter = 0
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            node, it = work[-1]
            nxt = next(it, None)
            if nxt is not None:
                if nxt not in index:
                    index[nxt] = low[nxt] = counter
                    counter += 1
                    stack.append(nxt)
                    on_stack.add(nxt)
                    work.append((nxt, iter(sorted(graph[nxt]))))
                elif nxt in on_stack:
                    low[node] = min(low[node], index[nxt])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                comp = []
                while True:
                    v = stack.pop()
                    on_stack.discard(v)
                    comp.append(v)
                    if v == node:
                        break
                if len(comp) > 1:
                    out.append(sorted(comp))
    return out


def test_no_import_cycles() -> None:
    cycles = _cycles(_graph())
    assert not cycles, "import cycles (module- and function-level imports):\n" + "\n".join(
        " <-> ".join(c) for c in cycles
    )


@pytest.mark.parametrize(
    "graph,expected",
    [
        ({"a": {"b"}, "b": {"a"}, "c": set()}, [["a", "b"]]),
        ({"a": {"b"}, "b": {"c"}, "c": set()}, []),
    ],
)
def test_cycle_finder_finds_cycles(graph: dict[str, set[str]], expected: list[list[str]]) -> None:
    assert _cycles(graph) == expected


def _router_prefixes(text: str) -> list[int]:
    """Lines of ``APIRouter(..., prefix=...)`` calls in a module's source."""
    return [
        node.lineno
        for node in ast.walk(ast.parse(text))
        if isinstance(node, ast.Call)
        and getattr(node.func, "id", getattr(node.func, "attr", None)) == "APIRouter"
        and any(kw.arg == "prefix" for kw in node.keywords)
    ]


def test_routers_write_their_paths_whole() -> None:
    """One prefix style (docs/architecture.md, api): no router of ``daemon/api/routes/`` has a
    prefix, so a route's path is the one its decorator says under ``/api/v1``."""
    found = [
        f"{path.relative_to(ROOT)}:{line}"
        for path in sorted((ROOT / "daemon" / "api" / "routes").rglob("*.py"))
        for line in _router_prefixes(path.read_text(encoding="utf-8"))
    ]
    assert found == [], f"routers with a prefix: {found}"
    assert _router_prefixes('r = APIRouter(prefix="/robots", tags=["robots"])\n') == [1]
