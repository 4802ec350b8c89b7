"""The registry of filter dialects: which module reads which file.

A dialect module exposes ``DIALECT`` (an object implementing
:class:`calib.programs.sites.Dialect`); the languages' registry
(:data:`calib.programs.formats.LANGUAGES`) names it, with the extensions it takes; nothing
else (CLI, service, page) names dialects. :func:`looks_like` (each language's signature in
the registry) is a cheap sniff of a file's text, so that a file whose content is another
dialect's than its extension says (a Fanuc ``.ls`` saved as ``.script``) is refused, saying
what it looks like, instead of being read as a program without targets.
"""

from __future__ import annotations

import importlib
from functools import cache
from pathlib import PurePath

from calib.programs import formats
from calib.programs.formats import LANGUAGES
from calib.programs.sites import Dialect, FilterInputError, Source

#: Dialect modules, imported on first use (the languages' registry's).
DIALECT_MODULES = tuple(lang.filter_module for lang in LANGUAGES.values())


@cache
def dialects() -> tuple[Dialect, ...]:
    """Every dialect, in the order of :data:`DIALECT_MODULES`."""
    return tuple(importlib.import_module(name).DIALECT for name in DIALECT_MODULES)


def extension(name: str) -> str:
    """Lower-case extension of a file name, with the dot (``"$config.dat"`` → ``".dat"``)."""
    return PurePath(name).suffix.lower()


def looks_like(source: Source) -> list[tuple[str, int]]:
    """The dialects whose signature the file's start matches: (dialect name, line)."""
    return formats.looks_like(source.text)


def is_empty(source: Source) -> bool:
    """No program text at all: no byte, or only white space (and a byte-order mark)."""
    return not source.text.strip(" \t\r\n\f\v\ufeff\x00\x1a")


def dialect_for(source: Source) -> Dialect:
    """The dialect of a file, by extension and then content.

    Raises
    ------
    FilterInputError
        An empty file; no dialect takes the extension; the content is another dialect's
        (the message says which); or none of those that take it recognises the content.
    """
    if is_empty(source):
        what = "0 bytes" if not source.text else "only white space"
        raise FilterInputError(source.name, f"empty file ({what}): no program to filter")
    ext = extension(source.name)
    by_ext = [d for d in dialects() if ext in d.extensions]
    if not by_ext:
        known = sorted({e for d in dialects() for e in d.extensions})
        raise FilterInputError(
            source.name,
            f"unknown program dialect (extension {ext or 'none'!r}; known: {', '.join(known)})",
        )
    names = ", ".join(d.name for d in by_ext)
    looks = looks_like(source)
    if looks and not any(name == d.name for name, _ in looks for d in by_ext):
        other, line = looks[0]
        lang = LANGUAGES[other]
        raise FilterInputError(
            source.name,
            f"the content is not {names} (extension {ext}): it looks like {lang.label} "
            f"({lang.looks}); give it its own extension ({', '.join(lang.extensions)})",
            line,
        )
    for d in by_ext:
        if d.claims(source):
            return d
    raise FilterInputError(source.name, f"the content is not {names} (extension {ext})", 1)
