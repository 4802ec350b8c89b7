"""Calibration samples and their CSV form (parsed from text; the caller reads the file).

CSV: a header with ``q1..q6`` (any case) in degrees and ``L`` (or ``length_mm``) in mm; an
optional ``anchor`` column (sensor position id), an optional ``group`` column (pose group
for grouped hold-out) and an optional ``t_s`` column (capture time [s], any origin, for the
drift model of :mod:`calib.drift`; without it the row order is the time). Other columns
(``x, y, z``, …) are ignored. Every error names the line (the header is line 1) and the
column, and nothing is returned on error.
"""

from __future__ import annotations

import array
import csv
import io
import math
import re
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import NoReturn

import numpy as np

from calib.csvtext import neutralise_cell, restore_cell
from calib.error_kinds import ErrorKind
from calib.kinematics import N_JOINTS, FloatArray
from calib.models import RobotModel
from calib.sample_fields import DEFAULT_ANCHOR

#: The indicator's reading range [mm]: the HY9648 shows the HY150-2000 drawstring sensor's
#: length from 0 to 2000 mm and flags anything outside as over or under range (its status
#: register, docs/hardware-protocols; the sampler refuses such a capture). A sample outside it
#: is not a measurement; a plan keeps its predicted readings inside it.
CABLE_MIN_MM = 0.0
CABLE_MAX_MM = 2000.0
#: How far inside the reading range a plan keeps a pose's predicted reading [mm]. The
#: prediction uses the nominal kinematics, whose tool point an uncalibrated robot misses by
#: a few mm (DH errors of the size of the paper's Table XII), and a fitted zero offset; 10 mm
#: covers both. The anchor guess's own error is the plan's ``anchor_uncertainty_mm``, added
#: to this.
READING_MARGIN_MM = 10.0
JOINT_COLUMNS = tuple(f"q{j + 1}" for j in range(N_JOINTS))
LENGTH_COLUMNS = ("l", "length_mm")

#: Rows converted to an array at a time while parsing, and checked at a time by
#: :func:`validate_values`: each numpy call holds the GIL only briefly, so a large import parsed
#: in a worker thread does not stall the event loop of the service.
_BLOCK_ROWS = 10_000

#: A decimal number as a CSV cell may spell it: digits, one optional point, an optional
#: exponent. No digit separators (Python's ``float("1_0")`` is 10), no ``nan``/``inf``, ASCII
#: digits only (``re.ASCII``: Arabic-Indic ``٧`` or fullwidth ``７`` are not numbers here).
_NUMBER = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?", re.ASCII)


class SampleError(ValueError):
    """Invalid sample data; ``row`` is the 1-based file line (None for header-level errors),
    ``message`` what is wrong without the row and column, ``kind`` the kind of failure
    (:class:`calib.error_kinds.ErrorKind`: ``CONFLICT`` for a pose outside the robot model's
    joint limits, a rule of the robot rather than of the data's form)."""

    def __init__(
        self,
        message: str,
        *,
        row: int | None = None,
        column: str | None = None,
        kind: ErrorKind = ErrorKind.INVALID,
    ) -> None:
        where = []
        if row is not None:
            where.append(f"row {row}")
        if column is not None:
            where.append(f"column {column!r}")
        super().__init__(f"{', '.join(where)}: {message}" if where else message)
        self.row = row
        self.column = column
        self.message = message
        self.kind = kind


@dataclass(frozen=True)
class SampleSet:
    """Calibration samples.

    Attributes
    ----------
    joints_deg : ndarray, shape (n, 6)
    length_mm : ndarray, shape (n,)
    anchor : tuple of str, length n
        Sensor position id per sample (default :data:`calib.sample_fields.DEFAULT_ANCHOR`).
    group : tuple of str or None, length n
        Pose group per sample, from a ``group`` column; None when absent.
    line : ndarray of int, shape (n,)
        Source line in the file (1-based, header = 1), for error messages.
    t_s : ndarray, shape (n,) or None
        Capture time [s] (any origin), from a ``t_s`` column; None when absent.
    """

    joints_deg: FloatArray
    length_mm: FloatArray
    anchor: tuple[str, ...]
    group: tuple[str, ...] | None = None
    line: np.ndarray | None = None
    t_s: FloatArray | None = None

    def __len__(self) -> int:
        return int(self.length_mm.shape[0])

    @property
    def anchor_ids(self) -> tuple[str, ...]:
        """Distinct anchor ids in order of first appearance."""
        return tuple(dict.fromkeys(self.anchor))

    def anchor_index(self) -> np.ndarray:
        ids = {a: i for i, a in enumerate(self.anchor_ids)}
        return np.array([ids[a] for a in self.anchor], dtype=int)

    def subset(self, rows: np.ndarray) -> SampleSet:
        rows = np.asarray(rows, dtype=int)
        return SampleSet(
            joints_deg=self.joints_deg[rows],
            length_mm=self.length_mm[rows],
            anchor=tuple(self.anchor[i] for i in rows),
            group=None if self.group is None else tuple(self.group[i] for i in rows),
            line=None if self.line is None else self.line[rows],
            t_s=None if self.t_s is None else self.t_s[rows],
        )

    def line_of(self, i: int) -> int:
        return int(self.line[i]) if self.line is not None else i + 2


def make_samples(
    joints_deg: FloatArray | Sequence[Sequence[float]],
    length_mm: FloatArray | Sequence[float],
    anchor: list[str] | tuple[str, ...] | None = None,
    group: list[str] | tuple[str, ...] | None = None,
    t_s: FloatArray | Sequence[float] | None = None,
) -> SampleSet:
    """Build and validate a :class:`SampleSet` from arrays or lists ((n, 6) deg and (n,) mm;
    ``t_s`` (n,) capture times [s], optional)."""
    q = np.asarray(joints_deg, dtype=float)
    length = np.asarray(length_mm, dtype=float)
    if q.ndim != 2 or q.shape[1] != N_JOINTS:
        raise SampleError(f"joints_deg must have shape (n, 6), got {q.shape}")
    if length.shape != (q.shape[0],):
        raise SampleError(f"length_mm must have shape ({q.shape[0]},), got {length.shape}")
    n = q.shape[0]
    anchors = tuple(anchor) if anchor is not None else (DEFAULT_ANCHOR,) * n
    times = None if t_s is None else np.asarray(t_s, dtype=float)
    if times is not None and times.shape != (n,):
        raise SampleError(f"t_s must have shape ({n},), got {times.shape}")
    s = SampleSet(
        q, length, anchors, tuple(group) if group is not None else None, np.arange(2, n + 2), times
    )
    validate_values(s)
    return s


def validate_values(samples: SampleSet) -> None:
    """Finite joints and lengths, lengths within the sensor range; errors name row and column
    (the first bad cell in file order). Vectorised, in blocks of rows."""
    q_all = np.asarray(samples.joints_deg, dtype=float)
    length_all = np.asarray(samples.length_mm, dtype=float)
    for start in range(0, max(len(length_all), 1), 5 * _BLOCK_ROWS):
        q = q_all[start : start + 5 * _BLOCK_ROWS]
        length = length_all[start : start + 5 * _BLOCK_ROWS]
        bad_q = ~np.isfinite(q)
        with np.errstate(invalid="ignore"):
            bad_len = ~np.isfinite(length) | (length < CABLE_MIN_MM) | (length > CABLE_MAX_MM)
        bad_rows = np.flatnonzero(bad_q.any(axis=1) | bad_len)
        if bad_rows.size:
            _raise_first(samples, start + int(bad_rows[0]), bad_q[bad_rows[0]])


def _raise_first(samples: SampleSet, i: int, bad_q: np.ndarray) -> NoReturn:
    """The :class:`SampleError` of row ``i`` (``bad_q``: its non-finite joints, shape (6,))."""
    if bad_q.any():
        j = int(np.flatnonzero(bad_q)[0])
        raise SampleError(
            "joint angle is not finite", row=samples.line_of(i), column=JOINT_COLUMNS[j]
        )
    value = float(samples.length_mm[i])
    if not math.isfinite(value):
        raise SampleError("cable length is not finite", row=samples.line_of(i), column="L")
    raise SampleError(
        f"cable length {value} mm is outside the sensor range "
        f"{CABLE_MIN_MM:.0f}..{CABLE_MAX_MM:.0f} mm",
        row=samples.line_of(i),
        column="L",
    )


def validate_joint_limits(samples: SampleSet, model: RobotModel) -> None:
    """Every joint angle within the model's limits (if it has any)."""
    limits = model.joint_limits_deg
    if limits is None:
        return
    bad = (samples.joints_deg < limits[:, 0]) | (samples.joints_deg > limits[:, 1])
    if np.any(bad):
        i, j = (int(v) for v in np.argwhere(bad)[0])
        raise SampleError(
            f"joint angle {samples.joints_deg[i, j]} deg is outside the limits "
            f"[{limits[j, 0]}, {limits[j, 1]}] of model {model.name!r}",
            row=samples.line_of(i),
            column=JOINT_COLUMNS[j],
            kind=ErrorKind.CONFLICT,
        )


def _header_columns(header: list[str]) -> tuple[dict[str, int], str]:
    """Column index by lower-case name, and the name of the length column. Raises
    :class:`SampleError` (row 1) on a duplicated column, a missing q1..q6 or length column,
    or both ``L`` and ``length_mm``."""
    cols: dict[str, int] = {}
    for i, name in enumerate(header):
        key = name.strip().lower()
        if key in cols:
            raise SampleError(
                f"duplicated column {name.strip()!r} (columns {cols[key] + 1} and {i + 1})",
                row=1,
                column=name.strip(),
            )
        cols[key] = i
    missing = [c for c in JOINT_COLUMNS if c not in cols]
    if missing:
        raise SampleError(f"missing column(s) {missing}; the header has {header}", row=1)
    lengths = [c for c in LENGTH_COLUMNS if c in cols]
    if not lengths:
        raise SampleError(
            f"missing column 'L' (cable length in mm); the header has {header}", row=1
        )
    if len(lengths) > 1:
        raise SampleError(
            "both 'L' and 'length_mm' are present; keep one cable length column", row=1
        )
    return cols, lengths[0]


def _number(cell: str, line_no: int, column: str) -> float:
    """A finite decimal number; :class:`SampleError` naming the row and column otherwise."""
    if _NUMBER.fullmatch(cell) is None:
        low = cell.lower().lstrip("+-")
        if low in ("nan", "inf", "infinity"):
            raise SampleError(f"not a finite number: {cell!r}", row=line_no, column=column)
        raise SampleError(f"not a number: {cell!r}", row=line_no, column=column)
    value = float(cell)
    if not math.isfinite(value):  # e.g. 1e999
        raise SampleError(f"not a finite number: {cell!r}", row=line_no, column=column)
    return value


def parse_samples_csv(text: str) -> SampleSet:
    """Parse CSV text into validated samples. Raises :class:`SampleError`.

    Strict: lines end in LF or CRLF (a bare CR is an error), a field holds at most
    131072 characters (the csv module's limit), column names are unique (case-insensitive),
    exactly one of ``L`` and ``length_mm``, numbers are plain decimals (no ``1_0``).
    """
    reader = csv.reader(io.StringIO(text))  # splits on LF only: a bare CR is a csv.Error
    try:
        return _parse_rows(reader)
    except csv.Error as exc:  # a bare CR, an over-long field, a stray quote
        raise SampleError(f"malformed CSV: {exc}", row=max(reader.line_num, 1)) from None


def _parse_rows(reader: Iterator[list[str]]) -> SampleSet:
    """The body of :func:`parse_samples_csv` after the reader is made."""
    try:
        header = next(reader)
    except StopIteration:
        raise SampleError("the file is empty; expected a header with q1..q6 and L") from None
    cols, length_col = _header_columns(header)
    anchor_col = cols.get("anchor")
    group_col = cols.get("group")
    time_col = cols.get("t_s")
    times: list[float] = []
    # Flat lists of floats and ints (objects the garbage collector does not track, so a large
    # file does not make every collection slower), turned into arrays block by block.
    values: list[float] = []  # the current block of rows, q1..q6, L each
    blocks: list[FloatArray] = []  # (k, 7) arrays, _BLOCK_ROWS rows each but the last
    anchors: list[str] = []
    groups: list[str] = []
    lines = array.array("q")
    wanted = [
        (cols[name], "L" if name == length_col else name) for name in (*JOINT_COLUMNS, length_col)
    ]
    for line_no, row in enumerate(reader, start=2):
        if not row or all(not cell.strip() for cell in row):
            continue
        for idx, shown in wanted:
            if idx >= len(row):
                raise SampleError("missing value", row=line_no, column=shown)
            values.append(_number(row[idx].strip(), line_no, shown))
        if len(values) == _BLOCK_ROWS * (N_JOINTS + 1):
            blocks.append(np.array(values, dtype=float).reshape(-1, N_JOINTS + 1))
            values = []
        anchor = row[anchor_col].strip() if anchor_col is not None and anchor_col < len(row) else ""
        anchors.append(restore_cell(anchor) or DEFAULT_ANCHOR)
        if group_col is not None:
            groups.append(restore_cell(row[group_col].strip()) if group_col < len(row) else "")
        if time_col is not None:
            if time_col >= len(row):
                raise SampleError("missing value", row=line_no, column="t_s")
            times.append(_number(row[time_col].strip(), line_no, "t_s"))
        lines.append(line_no)
    if not lines:
        raise SampleError("no data rows after the header")
    if values:
        blocks.append(np.array(values, dtype=float).reshape(-1, N_JOINTS + 1))
    table = np.concatenate(blocks)  # (n, 7): q1..q6 [deg], L [mm]
    samples = SampleSet(
        joints_deg=table[:, :N_JOINTS].copy(),
        length_mm=table[:, N_JOINTS].copy(),
        anchor=tuple(anchors),
        group=tuple(groups) if group_col is not None else None,
        line=np.frombuffer(lines, dtype=np.int64).astype(int),
        t_s=np.array(times, dtype=float) if time_col is not None else None,
    )
    validate_values(samples)
    return samples


def samples_to_csv(samples: SampleSet) -> str:
    """CSV text in the format :func:`parse_samples_csv` reads. Numbers with 6 decimals; the
    text cells (``anchor``, ``group``) through :func:`neutralise_cell` (no formula injection
    when the file is opened in a spreadsheet; the parser reverses it)."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    header = [*JOINT_COLUMNS, "L", "anchor"] + (["group"] if samples.group is not None else [])
    header += ["t_s"] if samples.t_s is not None else []
    writer.writerow(header)
    for i in range(len(samples)):
        row = [f"{v:.6f}" for v in samples.joints_deg[i]]
        row += [f"{samples.length_mm[i]:.6f}", neutralise_cell(samples.anchor[i])]
        if samples.group is not None:
            row.append(neutralise_cell(samples.group[i]))
        if samples.t_s is not None:
            row.append(f"{samples.t_s[i]:.3f}")
        writer.writerow(row)
    return out.getvalue()


def capture_times_s(t_end_s: list[float | None], captured: list[bool]) -> FloatArray | None:
    """The capture times of samples in storage order, for the drift model of
    :mod:`calib.drift`, or None when they do not count (then the row order is the time).

    They count only when there are at least two samples, every one was captured (an import
    has one timestamp for all its rows), each has its time, and the times never go back.

    Parameters
    ----------
    t_end_s : list of float or None, length n
        The end of each capture [s epoch]; None: not known.
    captured : list of bool, length n
        Whether each sample was captured live (False: imported).

    Returns
    -------
    ndarray, shape (n,), or None
        [s] since the first sample.
    """
    n = len(t_end_s)
    if n < 2 or not all(captured) or any(t is None for t in t_end_s):
        return None
    stamps: FloatArray = np.array(t_end_s, dtype=float)
    if not bool(np.all(np.diff(stamps) >= 0)):
        return None
    out: FloatArray = stamps - stamps[0]
    return out


def known_pose_index(
    known_deg: FloatArray | Sequence[Sequence[float]],
    q_deg: FloatArray | Sequence[float],
    tol_deg: float,
) -> int | None:
    """The rule for a repeated capture: the first pose of ``known_deg`` that ``q_deg`` is
    closer than ``tol_deg`` to in every joint, or None when ``q_deg`` is a new pose. Auto
    capture skips such a pose; a manual capture there is refused unless the operator confirms
    it (``POST /campaigns/{id}/captures`` with ``repeat``).

    Parameters
    ----------
    known_deg : ndarray, shape (n, 6) [deg]
        The campaign's captured poses.
    q_deg : ndarray, shape (6,) [deg]
    tol_deg : float
        Largest difference per joint that still counts as the same pose [deg].
    """
    known = np.asarray(known_deg, dtype=float).reshape(-1, N_JOINTS)
    near = np.flatnonzero(np.all(np.abs(known - np.asarray(q_deg, dtype=float)) < tol_deg, axis=1))
    return int(near[0]) if near.size else None
