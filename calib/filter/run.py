"""Filter a set of program files: bytes in, bytes and a summary out (no file I/O, no clock).

:func:`filter_files` groups the files by dialect (:mod:`calib.programs.dialects`), parses each
dialect's files together, corrects every target (:mod:`calib.filter.correct`), and writes the
corrected numbers back into each file's own text. A file that cannot be parsed gets an error
naming the file and line and no output; the others are still filtered. Files without
targets come back unchanged.

Exit codes (:attr:`FilterRun.exit_code`): :data:`EXIT_OK` when every target was corrected
(targets left out on purpose with ``--only`` or ``--keep-joint-targets``, and points that no
move of the given files uses, do not count), :data:`EXIT_LEFT` when some were left unchanged
(unreachable or skipped, named in the summary with their reason), :data:`EXIT_BAD_INPUT` when
a file could not be read (its error names it) or ``only`` names a target that no file has.

Every target left unchanged has a reason: one a dialect or the core leaves empty is filled in
here as a bug to report, never shown blank.
"""

from __future__ import annotations

import dataclasses
import json
import math
import re
from collections import defaultdict
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from calib.filter.correct import Calibration, correct_targets
from calib.filter.kin import drives_no_external_axes
from calib.programs.dialects import dialect_for
from calib.programs.sites import (
    EXTERNAL_AXIS_REASON,
    READ_ONLY_REASON,
    Correction,
    Dialect,
    Edit,
    EditTuple,
    FilterInputError,
    FrameTables,
    Source,
    Target,
    apply_edits,
)
from calib.programs.sites import UNUSED_REASON as UNUSED_REASON
from calib.result import DH_KEYS, CalibrationResult, ResultLike

if TYPE_CHECKING:
    from calib.models import RobotModel

EXIT_OK = 0
EXIT_BAD_INPUT = 2
#: Some targets were left unchanged (unreachable, or skipped with a reason).
EXIT_LEFT = 3
#: Reasons that mean "left out on purpose" (not counted against the exit code).
DELIBERATE = ("not selected (--only)", "joint target kept (--keep-joint-targets)")
#: Targets the core corrects in one batch: its arrays grow with the batch (bench/filter.md),
#: so a long program goes in batches of targets that do not refer to each other
#: (:func:`batches`).
CORRECT_BATCH = 2000
#: Decimals of the joints [deg] and of the written values' neighbours in the summary.
SUMMARY_JOINT_DECIMALS = 4

#: How a reason becomes its group (the same kind of reason for many targets): a leading
#: ``line N:``, a parenthesis with figures, and decimal figures are dropped.
_GROUP_RULES = (
    (re.compile(r"^line \d+: "), ""),
    (re.compile(r" ?\([^()]*\d[^()]*\)"), ""),
    (re.compile(r"[-+]?\d+\.\d+"), "…"),
    (re.compile(r"^follows \S+, which"), "follows a target which"),
    (re.compile(r"^the previous move's target \S+ has"), "the previous move's target has"),
)


def reason_group(status: str, reason: str) -> str:
    """The group of a left target in the summary: ``status: reason`` without the details
    that differ from target to target (line numbers, figures); ``unused`` for points that no
    move uses."""
    if is_unused(reason):
        return "unused: " + UNUSED_REASON
    for pattern, repl in _GROUP_RULES:
        reason = pattern.sub(repl, reason)
    return f"{status}: {reason}"


def is_unused(reason: str) -> bool:
    """A point that no move of the given files uses (:data:`UNUSED_REASON`)."""
    return reason.startswith(UNUSED_REASON)


@dataclass
class FilterRun:
    """The outcome of :func:`filter_files`.

    Attributes
    ----------
    outputs : dict of str to bytes
        Every input file that could be read, by name: filtered, or unchanged when it holds
        no target (or nothing moved).
    errors : list of FilterInputError
        Files that could not be read (no output for them), and names of ``only`` that no
        target has.
    targets : list of Target
    corrections : list of Correction
        One per target.
    edits : dict of str to list of EditTuple
        Per file, the edits written into it, batch by batch and target by target, as exact
        tuples ``(file, start, end, new)`` (:data:`calib.programs.sites.EditTuple`).
    written : list of tuple of (str, int, int)
        Per target, where its edits are: ``edits[file][first:last]`` for each ``(file,
        first, last)`` (exact tuples of atoms, which the garbage collector stops tracking).
    sources : dict of str to Source
        The readable files, for the text and line of each edit in the summary.
    dialects : dict of str to str
        File name → dialect name.
    unknown_only : list of str
        Names given in ``only`` that no target of the readable files has.
    """

    outputs: dict[str, bytes] = field(default_factory=dict)
    errors: list[FilterInputError] = field(default_factory=list)
    targets: list[Target] = field(default_factory=list)
    corrections: list[Correction] = field(default_factory=list)
    edits: dict[str, list[EditTuple]] = field(default_factory=dict)
    written: list[tuple[tuple[str, int, int], ...]] = field(default_factory=list)
    sources: dict[str, Source] = field(default_factory=dict)
    dialects: dict[str, str] = field(default_factory=dict)
    unknown_only: list[str] = field(default_factory=list)

    def rows(self) -> list[dict[str, Any]]:
        """One summary row per target, by file and line (:meth:`iter_rows`)."""
        return list(self.iter_rows())

    def iter_rows(self) -> Iterator[dict[str, Any]]:
        """One summary row per target, by file and line, made as they are taken (JSON-able;
        NaN → None).

        A corrected target's row adds ``values`` (each rewritten number: line, old and new
        text), ``joints_deg`` (the joints the controller reaches the corrected target at, on
        its own branch: what the pendant shows there) and ``nominal_joints_deg`` (the
        original target's); a left target's row its ``group`` (:func:`reason_group`).
        """

        def num(v: float, nd: int) -> float | None:
            return None if not math.isfinite(v) else round(float(v), nd)

        def joints(q: Any) -> list[float] | None:
            if q is None:
                return None
            return [round(float(v), SUMMARY_JOINT_DECIMALS) for v in q]

        written = self.written or [()] * len(self.targets)
        order = {name: k for k, name in enumerate(self.dialects)}
        targets = self.targets
        by_place = sorted(
            range(len(targets)),
            key=lambda i: (order.get(targets[i].file, len(order)), targets[i].line),
        )
        for i in by_place:
            t, c = targets[i], self.corrections[i]
            tool = sorted({u.tool_name for u in t.uses})
            work = sorted({u.work_name for u in t.uses})
            row: dict[str, Any] = {
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
            if c.status == "corrected":
                row["values"] = [v for span in written[i] for v in self._values(*span)]
                row["joints_deg"] = joints(c.joints_deg)
                row["nominal_joints_deg"] = joints(c.nominal_joints_deg)
            else:
                row["group"] = reason_group(c.status, c.reason)
            yield row

    def _values(self, file: str, first: int, last: int) -> list[dict[str, Any]]:
        """The numbers a target's correction rewrote: line, old and new text."""
        if first == last:
            return []
        src = self.sources[file]
        return [
            {"line": src.line_of(start), "old": src.text[start:end], "new": new}
            for _file, start, end, new in self.edits[file][first:last]
        ]

    @property
    def unused(self) -> int:
        """Points that no move of the given files uses (reported, not counted as left)."""
        return sum(1 for c in self.corrections if c.status != "corrected" and is_unused(c.reason))

    @property
    def left(self) -> int:
        """Targets left unchanged that were meant to be corrected."""
        return sum(
            1
            for c in self.corrections
            if c.status != "corrected"
            and c.reason not in DELIBERATE
            and not is_unused(c.reason)
            and not c.reason.startswith(READ_ONLY_REASON)
        )

    @property
    def exit_code(self) -> int:
        if self.errors:
            return EXIT_BAD_INPUT
        return EXIT_LEFT if self.left else EXIT_OK

    def summary(
        self, extra: Mapping[str, Any] | None = None, *, targets: bool = True
    ) -> dict[str, Any]:
        """The ``filter-summary.json`` mapping (without ``targets`` unless asked: then
        :meth:`iter_rows` gives them one by one, and :func:`summary_text` writes them)."""
        counts: dict[str, int] = defaultdict(int)
        groups: dict[str, int] = defaultdict(int)
        for c in self.corrections:
            counts[c.status] += 1
            if c.status != "corrected":
                groups[reason_group(c.status, c.reason)] += 1
        per_file: dict[str, int] = defaultdict(int)
        for t in self.targets:
            per_file[t.file] += 1
        files = [
            {
                "file": name,
                "dialect": dialect,
                "targets": per_file[name],
                "written": name in self.outputs,
            }
            for name, dialect in self.dialects.items()
        ]
        out = {
            **(dict(extra) if extra else {}),
            "exit_code": self.exit_code,
            "counts": {
                "targets": len(self.targets),
                **counts,
                "left": self.left,
                "unused": self.unused,
            },
            "left_by_reason": dict(sorted(groups.items(), key=lambda kv: (-kv[1], kv[0]))),
            "files": files,
            "errors": [{"file": e.file, "line": e.line, "message": str(e)} for e in self.errors],
        }
        if targets:
            out["targets"] = self.rows()
        return out


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


def batches(targets: Sequence[Target], size: int | None = None) -> list[list[int]]:
    """The targets' indices in batches of at most ``size`` (default :data:`CORRECT_BATCH`)
    that the core can correct apart: targets that refer to each other (one follows another,
    one starts from another's joints, two share a name in a file) stay in one batch, in
    their order; a group larger than ``size`` is a batch of its own."""
    size = CORRECT_BATCH if size is None else size
    n = len(targets)
    if n <= size:
        return [list(range(n))] if n else []
    parent = list(range(n))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    first: dict[tuple[str, str], int] = {}
    for i, t in enumerate(targets):
        k = first.setdefault((t.file, t.name), i)
        if k != i:
            parent[root(i)] = root(k)
    for i, t in enumerate(targets):
        after = t.configuration.after if t.configuration is not None else None
        for other in (t.follows, after):
            linked = first.get((t.file, other)) if other is not None else None
            if linked is not None:
                parent[root(i)] = root(linked)
    groups: dict[int, list[int]] = {}
    for i in range(n):
        groups.setdefault(root(i), []).append(i)
    out: list[list[int]] = []
    current: list[int] = []
    for group in sorted(groups.values(), key=lambda g: g[0]):
        if current and len(current) + len(group) > size:
            out.append(sorted(current))
            current = []
        current.extend(group)
    if current:
        out.append(sorted(current))
    return out


def _without_external_axes(targets: Iterable[Target]) -> None:
    """A controller that drives no external axis ignores the values a target carries for
    them (``[controller] external_axes = 0``): such targets are corrected, their values kept."""
    for t in targets:
        if t.problem.startswith(EXTERNAL_AXIS_REASON):
            t.problem = ""


def _with_reasons(
    corrections: list[Correction], parsed: list[tuple[Dialect, Target]]
) -> list[Correction]:
    """Every correction, a left one without a reason given one that says so."""
    out = corrections
    for k, c in enumerate(corrections):
        if c.status != "corrected" and not c.reason.strip():
            if out is corrections:
                out = list(corrections)
            why = (
                f"{c.status} without a reason (a bug of the filter's {parsed[k][0].name} "
                "dialect or core: please report it)"
            )
            out[k] = dataclasses.replace(c, reason=why)
    return out


def _render(
    dialect: Dialect, t: Target, c: Correction, edits: dict[str, list[EditTuple]]
) -> tuple[tuple[str, int, int], ...]:
    """Append a corrected target's edits to ``edits`` (per file); where they are (the
    :attr:`FilterRun.written` entry)."""
    by_file: dict[str, list[Edit]] = {}
    for e in dialect.render(t, c):
        by_file.setdefault(e.file, []).append(e)
    spans = []
    for file, new in by_file.items():
        mine = edits[file]
        spans.append((file, len(mine), len(mine) + len(new)))
        # Exact tuples: the collector stops tracking them (never a named tuple).
        mine.extend((e.file, e.start, e.end, e.new) for e in new)
    return tuple(spans)


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
    run = FilterRun()
    names = [n for n, _ in files]
    dup = {n for n in names if names.count(n) > 1}
    if dup:
        raise ValueError(f"files: the same name given twice: {', '.join(sorted(dup))}")
    frames = frames or FrameTables()
    groups: dict[str, tuple[Dialect, list[Source]]] = {}
    for name, data in files:
        src = Source.from_bytes(name, data)
        try:
            d = dialect_for(src)
        except FilterInputError as exc:
            run.errors.append(exc)
            continue
        groups.setdefault(d.name, (d, []))[1].append(src)
        run.dialects[name] = d.name
    parsed: list[tuple[Dialect, Target]] = []
    readable: list[Source] = []
    for d, group in groups.values():
        ok, targets = _parse_group(d, group, frames, run.errors)
        readable.extend(ok)
        parsed.extend((d, t) for t in targets)
    run.targets = [t for _, t in parsed]
    if drives_no_external_axes(cal.nominal):
        _without_external_axes(run.targets)
    if only is not None:
        have = {t.name.lower() for t in run.targets}
        run.unknown_only = [s for s in only if s.lower() not in have]
        if run.unknown_only:
            run.errors.append(
                FilterInputError(
                    "only",
                    f"no target named {', '.join(run.unknown_only)} in the given files "
                    "(names match without regard to case)",
                )
            )
    # Batch by batch: correct, write the edits, and let go of each written target's site
    # (its numbers: the edits hold what the summary shows), so a long program does not
    # keep every number of every target to the end.
    corrections: list[Correction | None] = [None] * len(run.targets)
    edits: dict[str, list[EditTuple]] = defaultdict(list)
    written: list[tuple[tuple[str, int, int], ...]] = [()] * len(run.targets)
    for batch in batches(run.targets):
        done = correct_targets(
            cal,
            [run.targets[i] for i in batch],
            keep_joint_targets=keep_joint_targets,
            only=only,
        )
        done = _with_reasons(done, [parsed[i] for i in batch])
        for i, c in zip(batch, done, strict=True):
            corrections[i] = c
            if c.status == "corrected":
                written[i] = _render(parsed[i][0], run.targets[i], c, edits)
        for i in batch:
            run.targets[i].site = None
    run.corrections = [c for c in corrections if c is not None]
    run.written = written
    run.sources = {src.name: src for src in readable}
    run.edits = dict(edits)
    for src in readable:
        text = apply_edits(src.text, edits.get(src.name, []))
        try:
            run.outputs[src.name] = src.encode(text)
        except FilterInputError as exc:  # never for digits, kept for safety
            run.errors.append(exc)
    return run


def robot_check(result: ResultLike, nominal: RobotModel) -> tuple[str, str]:
    """Whether a ``result.json`` mapping is of the nominal model: ``(warning, error)``, each
    empty when there is none.

    The warning: the result names another robot than the nominal model. The error: its DH
    table differs from the nominal one by more than a calibration moves a parameter
    (:data:`calib.identify.plausibility.PLAUSIBLE_DH_MM`,
    :data:`calib.identify.plausibility.PLAUSIBLE_DH_DEG`), the first such entry named: another
    arm's table, whose correction would be nonsense.
    """
    from calib.identify.plausibility import PLAUSIBLE_DH_DEG, PLAUSIBLE_DH_MM

    res = CalibrationResult.of(result)
    named = res.robot
    warning = ""
    if named and named != nominal.name:
        warning = f"the result is of robot {named!r}, the nominal model is {nominal.name!r}"
    for j, row in enumerate((res.dh or ())[: len(nominal.dh_table)]):
        for k, (key, v) in enumerate(zip(DH_KEYS, row.values(), strict=True)):
            if not math.isfinite(v):
                continue
            ref = float(nominal.dh_table[j][k])
            diff = float(v) - ref
            if key.endswith("_deg"):
                diff = (diff + 180.0) % 360.0 - 180.0
            bound = PLAUSIBLE_DH_DEG if key.endswith("_deg") else PLAUSIBLE_DH_MM
            if abs(diff) > bound:
                return warning, (
                    f"the result's DH table is not of the nominal model {nominal.name!r}: "
                    f"joint {j + 1} {key} is {float(v):g} there and {ref:g} in the model "
                    f"(a calibration moves it by at most {bound:g}); give the result's "
                    "own robot with --robot"
                )
    return warning, ""


def summary_text(head: Mapping[str, Any], rows: Iterable[Mapping[str, Any]]) -> str:
    """``filter-summary.json``'s text: ``head`` (:meth:`FilterRun.summary` without targets)
    indented, then ``"targets"``, one line per row (JSON's C encoder on each row: an
    indented dump of 10,000 rows goes through the pure-Python encoder and holds every piece
    of the text at once)."""
    lines = ["    " + json.dumps(r) for r in rows]
    text = json.dumps({**head, "targets": []}, indent=2)  # ends with '"targets": []\n}'
    if not lines:
        return text + "\n"
    return text[: -len("[]\n}")] + "[\n" + ",\n".join(lines) + "\n  ]\n}\n"
