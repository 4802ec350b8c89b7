"""The command line's shape: ``--help`` loads no heavy library and reads whole at 80 columns,
and only ``daemon/cli/`` may import the emulated cell."""

from __future__ import annotations

import ast
import inspect
import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import click
import pytest
import typer.main

from calib.identify import METHODS
from daemon.cli import app, calibration, demo

REPO = Path(__file__).resolve().parents[1]

# What the service, the identification and the drivers need, but ``--help`` does not.
HEAVY = ("fastapi", "uvicorn", "scipy", "pymodbus", "sqlite_utils", "numpy", "calib", "simulator")
# calib.options is standard library only: the CLI builds its identification options from it;
# calib.programs.formats (the program formats' names) and calib.planning.options (the plan's
# defaults, which `plan --help` names) likewise; calib.planning loads its other names lazily.
ALLOWED = {
    "calib",
    "calib.options",
    "calib.programs",
    "calib.programs.formats",
    "calib.default_robot",
    "calib.planning",
    "calib.planning.options",
}


def _imported_modules(argv: list[str], exit_code: int = 0) -> set[str]:
    """Top-level names of every module ``python -X importtime ARGV`` imported."""
    proc = subprocess.run(
        [sys.executable, "-X", "importtime", *argv],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert proc.returncode == exit_code, proc.stderr[-2000:]
    names = set()
    for line in proc.stderr.splitlines():
        if line.startswith("import time:") and "|" in line:
            module = line.rsplit("|", 1)[1].strip()
            if module not in ALLOWED:
                names.add(module.split(".")[0])
    assert "daemon" in names, proc.stderr[-2000:]  # the parse found the import lines
    return names


@pytest.mark.parametrize(
    "argv",
    [
        ["--help"],
        ["identify", "--help"],
        ["compare", "--help"],
        ["serve", "--help"],
        ["simulate", "--help"],
        ["db", "export", "--help"],
        ["plan", "--help"],
        ["program", "--help"],
        ["filter", "--help"],
        ["robots", "from-ur", "--help"],
    ],
)
def test_help_imports_no_heavy_library(argv: list[str]) -> None:
    loaded = _imported_modules(["-m", "daemon.cli", *argv])
    assert "typer" in loaded
    assert not loaded & set(HEAVY), sorted(loaded & set(HEAVY))


#: Text columns of ``--help`` at COLUMNS=80: typer's rich panel indents the prose by one
#: column and keeps one free at the right.
HELP_TEXT_COLUMNS = 78


def _help_texts(command: click.Command, path: str) -> Iterator[tuple[str, str]]:
    """``(where, text)`` of every help text of ``command`` and its subcommands."""
    yield path, command.help or ""
    for param in command.params:
        yield f"{path} {param.name}", getattr(param, "help", None) or ""
    for name, sub in getattr(command, "commands", {}).items():
        yield from _help_texts(sub, f"{path} {name}")


def test_help_paragraphs_break_only_where_every_line_fits_80_columns() -> None:
    """typer's rich help keeps a line break inside a paragraph and re-wraps the lines, so a
    docstring wrapped at 100 columns shows at 80 as lines broken mid-sentence. A paragraph is
    one line (rich wraps it), or short lines on purpose (a list, each line shown whole)."""
    broken = [
        (where, line)
        for root, name in ((app, "cablecal"), (demo.app, "python -m daemon.cli.demo"))
        for where, text in _help_texts(typer.main.get_command(root), name)
        for paragraph in inspect.cleandoc(text).split("\n\n")
        if "\n" in paragraph.strip()
        for line in paragraph.strip().splitlines()
        if len(line) > HELP_TEXT_COLUMNS
    ]
    assert broken == []


def test_identify_help_shows_each_exit_code_whole_at_80_columns() -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "daemon.cli", "identify", "--help"],
        cwd=REPO,
        env={**os.environ, "COLUMNS": "80", "NO_COLOR": "1"},
        capture_output=True,
        text=True,
        timeout=60,
        check=True,
    )
    lines = [line.strip() for line in proc.stdout.splitlines()]
    assert max(len(line) for line in proc.stdout.splitlines()) <= 80
    for code in (
        "1 the solver did not converge (result.json is still written)",
        "2 bad input (nothing written)",
        "3 with --strict: physically implausible result (result.json is still written)",
    ):
        assert code in lines, proc.stdout


def test_a_command_still_imports_what_it_uses() -> None:
    """The property above is not vacuous: running a command loads its libraries."""
    loaded = _imported_modules(["-m", "daemon.cli", "compare", "--methods", "nope"], exit_code=2)
    assert {"numpy", "calib"} <= loaded


def test_the_cli_method_names_are_calibs() -> None:
    assert calibration.METHODS == METHODS


def test_only_daemon_cli_imports_the_simulator() -> None:
    offenders = []
    for path in sorted((REPO / "daemon").rglob("*.py")):
        if (REPO / "daemon" / "cli") in path.parents:
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                names = [node.module or ""]
            else:
                continue
            offenders += [
                f"{path.relative_to(REPO)}:{node.lineno}"
                for n in names
                if n.split(".")[0] == "simulator"
            ]
    assert offenders == []


def test_the_simulator_imports_no_daemon() -> None:
    """The simulator owns its entry (``python -m simulator``); the CLI calls it, never the
    other way round."""
    offenders = []
    for path in sorted((REPO / "simulator").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                names = [node.module or ""]
            else:
                continue
            offenders += [
                f"{path.relative_to(REPO)}:{node.lineno}"
                for n in names
                if n.split(".")[0] == "daemon"
            ]
    assert offenders == []


@pytest.mark.parametrize(("preset", "expected"), [(None, "1"), ("3", "3")])
def test_the_command_runs_numpy_with_one_blas_thread_unless_told(
    preset: str | None, expected: str
) -> None:
    """daemon.process.blas: the cablecal command defaults BLAS to one thread before numpy loads,
    and an
    operator's own setting wins. Checked in the child's environment after importing the CLI."""
    import os

    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    if preset is not None:
        env["OPENBLAS_NUM_THREADS"] = preset
    code = "import os, daemon.cli; print(os.environ['OPENBLAS_NUM_THREADS'])"
    proc = subprocess.run(
        [sys.executable, "-c", code], cwd=REPO, env=env, capture_output=True, text=True, timeout=60
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.strip() == expected
