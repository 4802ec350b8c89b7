"""The robot library's files (:mod:`calib.robots`): names, text, info lines; standard library only.

:mod:`calib.models` reads the library through this module (so the package's
:func:`calib.robots.library_model`, which parses with :mod:`calib.models`, makes no cycle).
The file format and the header lines are described in :mod:`calib.robots`.
"""

from __future__ import annotations

import re
import tomllib
from dataclasses import dataclass
from importlib import resources
from typing import Any

#: A library name: lower-case words and digits joined by single dashes.
NAME_PATTERN = re.compile(r"[a-z0-9]+(?:-[a-z0-9]+)*")
#: The header keys :func:`library_info` reads from a file's leading comment.
INFO_KEYS = ("title", "maker", "payload_kg", "reach_mm")
_SUFFIX = ".toml"


class LibraryError(KeyError):
    """An unknown library name; the message names the known ones."""

    def __init__(self, name: str) -> None:
        super().__init__(name)
        self.name = name
        self.message = f"unknown built-in robot {name!r}; known: {', '.join(library_names())}"

    def __str__(self) -> str:
        return self.message


def _folder() -> Any:
    return resources.files("calib.robots").joinpath("library")


def library_names() -> list[str]:
    """Every built-in arm's name, sorted."""
    names = (
        entry.name[: -len(_SUFFIX)]
        for entry in _folder().iterdir()
        if entry.name.endswith(_SUFFIX) and entry.is_file()
    )
    return sorted(names)


def library_text(name: str) -> str:
    """The model file of arm ``name``, as stored (comments included).

    Raises
    ------
    LibraryError
        ``name`` is not in the library.
    """
    if not NAME_PATTERN.fullmatch(name) or name not in library_names():
        raise LibraryError(name)
    text: str = _folder().joinpath(name + _SUFFIX).read_text(encoding="utf-8")
    return text


def library_mapping(name: str) -> dict[str, Any]:
    """The parsed (not yet validated) model mapping of arm ``name``."""
    return tomllib.loads(library_text(name))


@dataclass(frozen=True)
class RobotInfo:
    """What ``cablecal robots`` lists of an arm (None where its file does not say)."""

    name: str
    title: str | None
    maker: str | None
    payload_kg: float | None
    reach_mm: float | None


def library_info(name: str) -> RobotInfo:
    """The ``# key: value`` lines of arm ``name``'s leading comment (:data:`INFO_KEYS`)."""
    found: dict[str, str] = {}
    for line in library_text(name).splitlines():
        if not line.startswith("#"):
            break
        key, sep, value = line[1:].partition(":")
        if sep and key.strip() in INFO_KEYS:
            found[key.strip()] = value.strip()

    def number(key: str) -> float | None:
        try:
            return float(found[key]) if key in found else None
        except ValueError:
            return None

    return RobotInfo(
        name, found.get("title"), found.get("maker"), number("payload_kg"), number("reach_mm")
    )


__all__ = [
    "INFO_KEYS",
    "NAME_PATTERN",
    "LibraryError",
    "RobotInfo",
    "library_info",
    "library_mapping",
    "library_names",
    "library_text",
]
