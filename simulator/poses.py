"""Pose lists of the emulated robot: a plan read from CSV, or a seeded spread of poses.

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
from calib.synthetic import TrueCell, random_poses_deg
from calib.tcp import joint_limits_deg


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


def flange_and_hook_z_mm(truth: TrueCell, q_deg: FloatArray) -> tuple[FloatArray, FloatArray]:
    """True heights [mm] of the flange origin and the hook point, each shape (n,),
    for poses ``(n, 6)`` [deg]."""
    dh = truth.model.dh_internal() + truth.theta[: 4 * N_JOINTS].reshape(N_JOINTS, 4)
    _, origin = forward_frames(dh, np.deg2rad(q_deg), truth.model.convention)
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
    limits = joint_limits_deg(truth.model)
    scaled = pool / (limits[:, 1] - limits[:, 0])
    chosen = [0]
    dist = np.linalg.norm(scaled - scaled[0], axis=1)
    for _ in range(n - 1):
        k = int(np.argmax(dist))
        chosen.append(k)
        dist = np.minimum(dist, np.linalg.norm(scaled - scaled[k], axis=1))
    return pool[chosen]
