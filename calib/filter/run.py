"""Filter a set of program files: bytes in, bytes and a summary out (no file I/O, no clock).

:func:`filter_files` groups the files by dialect (:mod:`calib.filter.dialects`), parses each
dialect's files together, corrects every target (:mod:`calib.filter.correct`), and writes the
corrected numbers back into each file's own text. A file that cannot be parsed gets an error
naming the file and line and no output; the others are still filtered. Files without
targets come back unchanged.

Exit codes (:attr:`FilterRun.exit_code`): :data:`EXIT_OK` when every target was corrected
(targets left out on purpose with ``--only`` or ``--keep-joint-targets`` do not count),
:data:`EXIT_LEFT` when some were left unchanged (unreachable or skipped, named in the
summary), :data:`EXIT_BAD_INPUT` when a file could not be read (its error names it).
"""

from __future__ import annotations

import gc
import math
from collections import defaultdict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from calib.filter.correct import Calibration, correct_targets
from calib.filter.dialects import dialect_for
from calib.filter.sites import (
    Correction,
    Dialect,
    Edit,
    FilterInputError,
    FrameTables,
    Source,
    Target,
    apply_edits,
)

EXIT_OK = 0
EXIT_BAD_INPUT = 2
#: Some targets were left unchanged (unreachable, or skipped with a reason).
EXIT_LEFT = 3
#: Reasons that mean "left out on purpose" (not counted against the exit code).
DELIBERATE = ("not selected (--only)", "joint target kept (--keep-joint-targets)")


@dataclass
class FilterRun:
    """The outcome of :func:`filter_files`.

    Attributes
    ----------
    outputs : dict of str to bytes
        Every input file that could be read, by name: filtered, or unchanged when it holds
        no target (or nothing moved).
    errors : list of FilterInputError
        Files that could not be read (no output for them).
    targets : list of Target
    corrections : list of Correction
        One per target.
    dialects : dict of str to str
        File name → dialect name.
    """

    outputs: dict[str, bytes] = field(default_factory=dict)
    errors: list[FilterInputError] = field(default_factory=list)
    targets: list[Target] = field(default_factory=list)
    corrections: list[Correction] = field(default_factory=list)
    dialects: dict[str, str] = field(default_factory=dict)

    def rows(self) -> list[dict[str, Any]]:
        """One summary row per target, by file and line (JSON-able; NaN → None)."""

        def num(v: float, nd: int) -> float | None:
            return None if not math.isfinite(v) else round(float(v), nd)

        out: list[dict[str, Any]] = []
        for t, c in zip(self.targets, self.corrections, strict=True):
            tool = sorted({u.tool_name for u in t.uses})
            work = sorted({u.work_name for u in t.uses})
            out.append(
                {
                    "file": t.file,
                    "line": t.line,
                    "name": t.name,
                    "kind": t.kind,
                    "status": c.status,
                    "reason": c.reason,
                    "shift_mm": num(c.shift_mm, 4),
                    "shift_deg": num(c.shift_deg, 5),
                    "configuration_kept": c.configuration_kept,
                    "sigma_at_tool_mm": num(c.sigma_mm, 4),
                    "tool": ",".join(tool),
                    "work_object": ",".join(work),
                }
            )
        order = {name: k for k, name in enumerate(self.dialects)}
        out.sort(key=lambda r: (order.get(str(r["file"]), len(order)), int(r["line"])))
        return out

    @property
    def left(self) -> int:
        """Targets left unchanged that were meant to be corrected."""
        return sum(
            1 for c in self.corrections if c.status != "corrected" and c.reason not in DELIBERATE
        )

    @property
    def exit_code(self) -> int:
        if self.errors:
            return EXIT_BAD_INPUT
        return EXIT_LEFT if self.left else EXIT_OK

    def summary(self, extra: Mapping[str, Any] | None = None) -> dict[str, Any]:
        """The ``filter-summary.json`` mapping."""
        counts: dict[str, int] = defaultdict(int)
        for c in self.corrections:
            counts[c.status] += 1
        files = []
        for name, dialect in self.dialects.items():
            n = sum(1 for t in self.targets if t.file == name)
            files.append(
                {"file": name, "dialect": dialect, "targets": n, "written": name in self.outputs}
            )
        return {
            **(dict(extra) if extra else {}),
            "exit_code": self.exit_code,
            "counts": {"targets": len(self.targets), **counts, "left": self.left},
            "files": files,
            "errors": [{"file": e.file, "line": e.line, "message": str(e)} for e in self.errors],
            "targets": self.rows(),
        }


def _parse_group(
    dialect: Dialect, sources: list[Source], frames: FrameTables, errors: list[FilterInputError]
) -> tuple[list[Source], list[Target]]:
    """Parse a dialect's files together; a file that fails is dropped (its error kept) and
    the rest parsed again."""
    todo = list(sources)
    while todo:
        try:
            return todo, dialect.parse(todo, frames)
        except FilterInputError as exc:
            bad = [s for s in todo if s.name == exc.file]
            if not bad:
                raise
            errors.append(exc)
            todo = [s for s in todo if s.name != exc.file]
    return [], []


def filter_files(
    cal: Calibration,
    files: Sequence[tuple[str, bytes]],
    *,
    frames: FrameTables | None = None,
    keep_joint_targets: bool = False,
    only: Sequence[str] | None = None,
) -> FilterRun:
    """Filter ``files`` (name, bytes) with a calibration; see the module docstring.

    Raises
    ------
    ValueError
        Two files with the same name.
    """
    # Parsing allocates a few hundred thousand small objects and frees none of them before
    # the end: the cyclic garbage collector would rescan them all, many times, for nothing
    # (about half the time of a 10,000-target program).
    was_enabled = gc.isenabled()
    gc.disable()
    try:
        return _filter_files(cal, files, frames, keep_joint_targets, only)
    finally:
        if was_enabled:
            gc.enable()


def _filter_files(
    cal: Calibration,
    files: Sequence[tuple[str, bytes]],
    frames: FrameTables | None,
    keep_joint_targets: bool,
    only: Sequence[str] | None,
) -> FilterRun:
    run = FilterRun()
    names = [n for n, _ in files]
    dup = {n for n in names if names.count(n) > 1}
    if dup:
        raise ValueError(f"files: the same name given twice: {', '.join(sorted(dup))}")
    frames = frames or FrameTables()
    groups: dict[str, tuple[Dialect, list[Source]]] = {}
    sources: dict[str, Source] = {}
    for name, data in files:
        src = Source.from_bytes(name, data)
        try:
            d = dialect_for(src)
        except FilterInputError as exc:
            run.errors.append(exc)
            continue
        sources[name] = src
        groups.setdefault(d.name, (d, []))[1].append(src)
        run.dialects[name] = d.name
    parsed: list[tuple[Dialect, Target]] = []
    readable: list[Source] = []
    for d, group in groups.values():
        ok, targets = _parse_group(d, group, frames, run.errors)
        readable.extend(ok)
        parsed.extend((d, t) for t in targets)
    run.targets = [t for _, t in parsed]
    run.corrections = correct_targets(
        cal, run.targets, keep_joint_targets=keep_joint_targets, only=only
    )
    edits: dict[str, list[Edit]] = defaultdict(list)
    for (d, t), c in zip(parsed, run.corrections, strict=True):
        if c.status == "corrected":
            for e in d.render(t, c):
                edits[e.file].append(e)
    for src in readable:
        text = apply_edits(src.text, edits.get(src.name, []))
        try:
            run.outputs[src.name] = src.encode(text)
        except FilterInputError as exc:  # never for digits, kept for safety
            run.errors.append(exc)
    return run
