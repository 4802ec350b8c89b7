"""The free-space guard: a write that would leave the state directory's file system with less
than its reserve is refused before anything is written.

SQLite fails half-way when the disk fills (``database or disk is full``), and a full disk
also stops the journal, the logs and the other services of the cell PC. So the routes that
make the store grow (a campaign, a CSV import, an identification whose result is stored)
ask :func:`check_space` first, with what they are about to write, and a refusal names the
free space and the reserve (the ``[requests] disk_reserve_mb`` setting); the API answers it
507 Insufficient Storage. Nothing of the request is written.
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Final

MIB: Final = 1024 * 1024
#: What one write costs the store beyond its payload: SQLite's write-ahead log holds each
#: changed page again until a checkpoint, and the indexes grow with the rows [factor].
WRITE_AMPLIFICATION: Final = 3


class NoSpace(Exception):
    """The write would leave less free space than the reserve (the message says how much)."""


def free_bytes(path: Path) -> int:
    """Free bytes for an unprivileged writer on the file system of ``path`` (its nearest
    existing parent)."""
    p = Path(path)
    while not p.exists() and p != p.parent:
        p = p.parent
    return int(shutil.disk_usage(p).free)


def check_space(path: Path, reserve_bytes: int, payload_bytes: int, what: str) -> None:
    """Raise :class:`NoSpace` if writing ``payload_bytes`` (times
    :data:`WRITE_AMPLIFICATION`) to the store under ``path`` would leave less than
    ``reserve_bytes`` free; ``what`` names the write in the message."""
    if reserve_bytes <= 0:
        return
    free = free_bytes(path)
    need = max(payload_bytes, 0) * WRITE_AMPLIFICATION
    if free - need < reserve_bytes:
        raise NoSpace(
            f"{what}: refused, nothing written: {free / MIB:.0f} MiB free on the state "
            f"directory's file system ({path}), {need / MIB:.1f} MiB needed, and "
            f"{reserve_bytes / MIB:.0f} MiB are kept free ([requests] disk_reserve_mb)"
        )
