"""What is given to ``cablecal filter`` beside the programs, and how bad input is reported.

:class:`FilterInputError` is the one error of the filter's input (a program, a frame table,
an option), naming the file and line; :class:`FrameTables` and :func:`parse_frames_toml` are
the user frames and tools of ``--frames`` (Fanuc ``UF``/``UT``). :mod:`calib.programs.sites`
re-exports all three, the names the dialects import.
"""

from __future__ import annotations

import math
import re
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from calib.kinematics import FloatArray
from calib.programs.rotations import frame, zyx_deg_to_matrix


class FilterInputError(ValueError):
    """A file cannot be filtered (unparseable, unknown dialect, bad frames); the message
    names the file and, where there is one, the line."""

    def __init__(self, file: str, message: str, line: int | None = None) -> None:
        where = f"{file}:{line}" if line is not None else file
        super().__init__(f"{where}: {message}")
        self.file = file
        self.message = message
        self.line = line

    def __reduce__(self) -> tuple[type[FilterInputError], tuple[str, str, int | None]]:
        """Pickled by its fields (a filter run's errors come back from a worker process)."""
        return (type(self), (self.file, self.message, self.line))


@dataclass(frozen=True)
class FrameTables:
    """User frames and tools given with ``--frames`` (Fanuc ``UF``/``UT``), numbered.

    ``uframe[n]`` is a work object in the base frame, ``utool[n]`` a TCP in the flange
    frame, both (4, 4) [mm]. Number 0 is the identity in both (and cannot be redefined).
    """

    uframe: Mapping[int, FloatArray] = field(default_factory=dict)
    utool: Mapping[int, FloatArray] = field(default_factory=dict)

    def get(self, kind: Literal["uframe", "utool"], number: int) -> FloatArray | None:
        """The frame, the identity for 0, None when not given."""
        if number == 0:
            return np.eye(4)
        table = self.uframe if kind == "uframe" else self.utool
        return table.get(number)


def parse_frames_toml(text: str, name: str = "frames") -> FrameTables:
    """``[uframe.N]`` and ``[utool.N]`` tables, each ``xyz_mm = [x, y, z]`` and ``wpr_deg =
    [w, p, r]`` (Fanuc: ``R = Rz(r) Ry(p) Rx(w)``), N = 1..99.

    Raises
    ------
    FilterInputError
        Naming the table and field.
    """
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise FilterInputError(name, f"not TOML: {exc}") from None
    out: dict[str, dict[int, FloatArray]] = {"uframe": {}, "utool": {}}
    for key, tables in data.items():
        if key not in out:
            raise FilterInputError(name, f"[{key}]: unknown table; expected uframe.N or utool.N")
        if not isinstance(tables, dict):
            raise FilterInputError(name, f"{key}: expected tables [{key}.N]")
        for num, body in tables.items():
            where = f"[{key}.{num}]"
            if not re.fullmatch(r"[1-9]\d?", str(num)):
                raise FilterInputError(name, f"{where}: the number must be 1..99")
            if not isinstance(body, dict) or set(body) != {"xyz_mm", "wpr_deg"}:
                raise FilterInputError(name, f"{where}: needs exactly xyz_mm and wpr_deg")
            vals = []
            for fld in ("xyz_mm", "wpr_deg"):
                v = body[fld]
                if (
                    not isinstance(v, list)
                    or len(v) != 3
                    or not all(
                        isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)
                        for x in v
                    )
                ):
                    raise FilterInputError(name, f"{where}.{fld}: expected 3 finite numbers")
                vals.append([float(x) for x in v])
            w, p, r = vals[1]
            out[key][int(num)] = frame(np.array(vals[0]), zyx_deg_to_matrix(r, p, w))
    return FrameTables(out["uframe"], out["utool"])
