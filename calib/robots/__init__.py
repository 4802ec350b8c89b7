"""The robot library: built-in arms a plant picks by name (``--robot NAME``, ``cablecal robots``).

One plain model file per arm in ``calib/robots/library/<name>.toml``, in the format of
:mod:`calib.models` (``--robot FILE.toml`` takes it as it is) with a ``[controller]`` table
(:mod:`calib.conventions`). A file's leading ``#`` comment names the maker's document its
dimensions and joint ranges come from and the check done (docs/robots.md), and carries these
``key: value`` lines, read by :func:`library_info`::

    # title: IRB 120-3/0.58            (the maker's designation)
    # maker: ABB
    # payload_kg: 3
    # reach_mm: 580

Names are lower-case words and digits joined by dashes (``abb-irb4600-60-205``). The folder is
a plain folder of files: adding an arm is adding a file. The files are read by
:mod:`calib.robots.files` (standard library only: ``cablecal robots`` lists without numpy).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from calib.robots.files import (
    INFO_KEYS,
    NAME_PATTERN,
    LibraryError,
    RobotInfo,
    library_info,
    library_mapping,
    library_names,
    library_text,
)

if TYPE_CHECKING:
    from calib.models import RobotModel


def library_model(name: str) -> RobotModel:
    """Arm ``name`` as a validated :class:`calib.models.RobotModel`."""
    from calib.models import parse_model_text

    return parse_model_text(library_text(name), "toml")


__all__ = [
    "INFO_KEYS",
    "NAME_PATTERN",
    "LibraryError",
    "RobotInfo",
    "library_info",
    "library_mapping",
    "library_model",
    "library_names",
    "library_text",
]
