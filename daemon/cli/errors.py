"""The command line's one way to refuse bad input: ``error: …`` on stderr, and an exit code;
and :func:`printable`, which every command applies to text from the store before printing it."""

from __future__ import annotations

import re

import typer
from rich.console import Console
from rich.markup import escape

#: Exit code of a command refused for bad input (nothing written).
EXIT_BAD_INPUT = 2

_err_console = Console(stderr=True)

#: C0 and C1 control characters and DEL, except the tab, the line feed and a CR before it.
_CONTROL = re.compile("[\x00-\x08\x0b\x0c\x0e-\x1f\x7f-\x9f]|\r(?!\n)")


def printable(text: str) -> str:
    """``text`` with every control character but tabs and line ends written as a Python
    escape (ESC as ``\\x1b``), so nothing from the store can act on the terminal (clear it,
    move the cursor, ring the bell) or hide a line."""
    return _CONTROL.sub(lambda m: m.group().encode("unicode_escape").decode("ascii"), text)


def fail(message: str, code: int = EXIT_BAD_INPUT) -> typer.Exit:
    """Print ``error: message`` on stderr and return the exit to raise.

    The message is escaped (a path may hold ``[...]``, which rich would take for markup; a
    name from the store may hold control characters: :func:`printable`) and soft-wrapped:
    the terminal folds a long line, so a path is never split by an inserted newline and can
    be copied whole.
    """
    text = escape(printable(message))
    _err_console.print(f"[bold red]error:[/] {text}", highlight=False, soft_wrap=True)
    return typer.Exit(code)
