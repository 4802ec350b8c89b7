"""The registry of filter dialects: which module reads which file.

A dialect module exposes ``DIALECT`` (an object implementing
:class:`calib.filter.sites.Dialect`) and is listed in :data:`DIALECT_MODULES`; nothing else
(CLI, service) names dialects.
"""

from __future__ import annotations

import importlib
from functools import cache
from pathlib import PurePath

from calib.filter.sites import Dialect, FilterInputError, Source

#: Dialect modules, imported on first use.
DIALECT_MODULES = (
    "calib.filter.rapid",
    "calib.filter.urscript",
    "calib.filter.krl",
    "calib.filter.fanuc_ls",
)


@cache
def dialects() -> tuple[Dialect, ...]:
    """Every dialect, in the order of :data:`DIALECT_MODULES`."""
    return tuple(importlib.import_module(name).DIALECT for name in DIALECT_MODULES)


def extension(name: str) -> str:
    """Lower-case extension of a file name, with the dot (``"$config.dat"`` → ``".dat"``)."""
    return PurePath(name).suffix.lower()


def dialect_for(source: Source) -> Dialect:
    """The dialect of a file, by extension and then content.

    Raises
    ------
    FilterInputError
        No dialect takes the extension, or none of those that do recognises the content.
    """
    ext = extension(source.name)
    by_ext = [d for d in dialects() if ext in d.extensions]
    if not by_ext:
        known = sorted({e for d in dialects() for e in d.extensions})
        raise FilterInputError(
            source.name,
            f"unknown program dialect (extension {ext or 'none'!r}; known: {', '.join(known)})",
        )
    for d in by_ext:
        if d.claims(source):
            return d
    names = ", ".join(d.name for d in by_ext)
    raise FilterInputError(source.name, f"the content is not {names} (extension {ext})", 1)
