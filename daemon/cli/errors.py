"""The command line's one way to refuse bad input: ``error: …`` on stderr, and an exit code."""

from __future__ import annotations

import typer
from rich.console import Console
from rich.markup import escape

#: Exit code of a command refused for bad input (nothing written).
EXIT_BAD_INPUT = 2

_err_console = Console(stderr=True)


def fail(message: str, code: int = EXIT_BAD_INPUT) -> typer.Exit:
    """Print ``error: message`` on stderr and return the exit to raise.

    The message is escaped (a path may hold ``[...]``, which rich would take for markup) and
    soft-wrapped: the terminal folds a long line, so a path is never split by an inserted
    newline and can be copied whole.
    """
    _err_console.print(f"[bold red]error:[/] {escape(message)}", highlight=False, soft_wrap=True)
    return typer.Exit(code)
