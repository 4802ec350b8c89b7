"""Pose lists of the emulated robot: a plan read from CSV or from a robot program, or a seeded
spread of poses.

A robot program (RAPID, URScript, KRL or Fanuc LS, as ``cablecal program`` writes them; the
format is recognised by its start, :func:`calib.programs.registry.detect_format`) is
read with :mod:`calib.programs`: its joint moves, in order, are the poses. The emulated robot
keeps its own timing (``move_time_s``, ``dwell_s``), not the program's speed and waits.

A plan CSV is what ``cablecal identify`` reads and ``cablecal plan`` writes: a header with
``q1..q6`` (any case, any column order) in degrees; other columns (``pose``, ``L``,
``extension_mm``, ``anchor``, …) are ignored. A file without a header (every cell of the first
row numeric) is read as 6 joint angles per row. Errors name the file line (the header is line
1) and the column.

The generated default poses are within the joint limits, keep the cable's extension and the
indicator's reading inside the sensor's stroke, keep the flange and the hook point above the
floor, and are spread out (farthest-point selection in joint space) so that they feed an
identification well. Everything here is for the EMULATED cell.
"""

from __future__ import annotations

import csv
import io
import math

import numpy as np

from calib.dataset import JOINT_COLUMNS, SampleError
from calib.kinematics import N_JOINTS, FloatArray, forward_frames
from calib.programs.common import ProgramError
from calib.programs.registry import detect_format, parse_program
from calib.synthetic import TrueCell, random_poses_deg


class PoseCsvError(SampleError):
    """Invalid pose CSV; the message names the source, the file line and the column."""


def _is_number(cell: str) -> bool:
    try:
        float(cell)
    except ValueError:
        return False
    return True


def _columns(header: list[str], source: str) -> list[int] | None:
    """Indices of ``q1..q6`` in ``header``; None when the first row is data (no header)."""
    cells = [c.strip() for c in header]
    if cells and all(_is_number(c) for c in cells if c):
        return None
    cols = {name.lower(): i for i, name in enumerate(cells)}
    missing = [c for c in JOINT_COLUMNS if c not in cols]
    if missing:
        raise PoseCsvError(f"{source}: missing column(s) {missing}; the header has {cells}", row=1)
    return [cols[c] for c in JOINT_COLUMNS]


def parse_poses_csv(
    text: str, source: str = "poses", limits_deg: FloatArray | None = None
) -> FloatArray:
    """Joint angles [deg] of a plan CSV, shape (n, 6), in file order.

    Parameters
    ----------
    text : str
        CSV text (see the module docstring).
    source : str
        Name used in error messages (the file path).
    limits_deg : ndarray, shape (6, 2), optional
        Joint limits [deg]; a value outside them is an error naming the row and the column.

    Raises
    ------
    PoseCsvError
        Missing ``q1..q6`` columns, a missing or non-numeric value, a value outside the
        limits, or no rows at all.
    """
    rows = list(csv.reader(io.StringIO(text)))
    first = next((i for i, r in enumerate(rows) if any(c.strip() for c in r)), None)
    if first is None:
        raise PoseCsvError(f"{source}: no poses (empty file)")
    cols = _columns(rows[first], source)
    start = first if cols is None else first + 1
    if cols is None:
        cols = list(range(N_JOINTS))
    out: list[list[float]] = []
    for line_no, row in enumerate(rows[start:], start=start + 1):
        if not any(c.strip() for c in row):
            continue
        values: list[float] = []
        for name, idx in zip(JOINT_COLUMNS, cols, strict=True):
            cell = row[idx].strip() if idx < len(row) else ""
            if not cell:
                raise PoseCsvError(f"{source}: missing value", row=line_no, column=name)
            try:
                value = float(cell)
            except ValueError:
                raise PoseCsvError(
                    f"{source}: not a number: {cell!r}", row=line_no, column=name
                ) from None
            if not math.isfinite(value):
                raise PoseCsvError(f"{source}: not finite: {cell!r}", row=line_no, column=name)
            if limits_deg is not None:
                lo, hi = limits_deg[len(values)]
                if not lo <= value <= hi:
                    raise PoseCsvError(
                        f"{source}: {value} deg is outside the joint limits [{lo}, {hi}] deg",
                        row=line_no,
                        column=name,
                    )
            values.append(value)
        out.append(values)
    if not out:
        raise PoseCsvError(f"{source}: no poses after the header")
    return np.array(out, dtype=float)


def parse_poses_file(
    text: str, source: str = "poses", limits_deg: FloatArray | None = None
) -> FloatArray:
    """Joint angles [deg], shape (n, 6), of a plan CSV (:func:`parse_poses_csv`) or of a robot
    program in any format of :mod:`calib.programs` (its joint moves in program order).

    Raises
    ------
    PoseCsvError
        A bad CSV or program (the message names the line), or a target outside the limits
        (naming the target, 1-based, and the joint).
    """
    fmt = detect_format(text)
    if fmt == "csv":
        return parse_poses_csv(text, source, limits_deg)
    try:
        program = parse_program(fmt, text)
    except ProgramError as exc:
        raise PoseCsvError(f"{source} ({fmt}): {exc}") from None
    q = np.array(program.joints_deg, dtype=float)
    if limits_deg is not None:
        bad = (q < limits_deg[:, 0]) | (q > limits_deg[:, 1])
        if bad.any():
            i, j = (int(v) for v in np.argwhere(bad)[0])
            raise PoseCsvError(
                f"{source} ({fmt}): target {i + 1}, q{j + 1}: {q[i, j]} deg is outside the joint "
                f"limits [{limits_deg[j, 0]}, {limits_deg[j, 1]}] deg"
            )
    return q


def flange_and_hook_z_mm(truth: TrueCell, q_deg: FloatArray) -> tuple[FloatArray, FloatArray]:
    """True heights [mm] of the flange origin and the hook point, each shape (n,),
    for poses ``(n, 6)`` [deg]."""
    dh = truth.model.dh_internal() + truth.theta[: 4 * N_JOINTS].reshape(N_JOINTS, 4)
    _, origin = forward_frames(dh, truth.model.table_rad(q_deg), truth.model.convention)
    return origin[:, -1, 2], truth.tool_positions_mm(q_deg)[:, 2]


def spread_poses_deg(
    truth: TrueCell,
    n: int,
    rng: np.random.Generator,
    *,
    min_z_mm: float = 0.0,
    pool_factor: int = 8,
    max_rounds: int = 50,
) -> FloatArray:
    """``n`` distinct, well spread poses [deg], shape (n, 6), for the true cell.

    A pool of ``pool_factor * n`` random poses from :func:`calib.synthetic.random_poses_deg`
    (joint limits, cable reading 50..1950 mm, extension 300..1950 mm) is filtered to the ones
    whose flange origin and hook point are at or above ``min_z_mm`` (the floor, base frame);
    then ``n`` are picked by farthest-point selection in joint space scaled by each joint's
    range, so no two poses are near-duplicates. Deterministic for a given ``rng`` state.

    Raises
    ------
    ValueError
        When fewer than ``n`` poses above the floor are found.
    """
    want = pool_factor * n
    pool = np.empty((0, N_JOINTS))
    for _ in range(max_rounds):
        cand = random_poses_deg(truth, want, rng)
        flange_z, hook_z = flange_and_hook_z_mm(truth, cand)
        pool = np.vstack([pool, cand[(flange_z >= min_z_mm) & (hook_z >= min_z_mm)]])
        if pool.shape[0] >= want:
            break
    if pool.shape[0] < n:
        raise ValueError(
            f"only {pool.shape[0]} of {n} random poses keep the flange above z = {min_z_mm} mm "
            "with the cable in range; lower robot.min_z_mm or move the anchor"
        )
    pool = pool[:want]
    limits = truth.model.limits_deg()
    scaled = pool / (limits[:, 1] - limits[:, 0])
    chosen = [0]
    dist = np.linalg.norm(scaled - scaled[0], axis=1)
    for _ in range(n - 1):
        k = int(np.argmax(dist))
        chosen.append(k)
        dist = np.minimum(dist, np.linalg.norm(scaled - scaled[k], axis=1))
    return pool[chosen]
