"""Helpers of the store tests (tests/store/): captures, CSV text, row counts."""

from __future__ import annotations

import math
import sqlite3
from pathlib import Path
from typing import Any

import numpy as np

from calib.dataset import parse_samples_csv
from daemon.sampler.capture import Capture, RawReading
from daemon.store import Store

ROBOT = "hsr-jr680"
#: Inside the built-in model's joint limits [deg], with a margin.
JOINT_RANGE_DEG = np.array(
    [[-170, 170], [-150, 80], [70, 290], [-350, 350], [-120, 120], [-350, 350]], dtype=float
)
REPO = Path(__file__).resolve().parents[2]


def make_capture(
    joints_deg: tuple[float, ...] | np.ndarray,
    length_mm: float,
    *,
    n_raw: int = 3,
    anchor: str = "A",
    mode: str = "manual",
    t0: float = 1_700_000_000.0,
) -> Capture:
    """A capture whose mean is ``joints_deg``/``length_mm``, with ``n_raw`` raw readings."""
    q = tuple(float(v) for v in joints_deg)
    raw = tuple(
        RawReading(t0 + 0.1 * k, q, length_mm + 0.001 * (k - (n_raw - 1) / 2))  # type: ignore[arg-type]
        for k in range(n_raw)
    )
    return Capture(
        joints_deg=q,  # type: ignore[arg-type]
        joints_std_deg=(0.001,) * 6,
        length_mm=float(length_mm),
        length_std_mm=0.0008,
        count=max(n_raw, 1),
        anchor=anchor,
        t_start_wall=t0,
        t_end_wall=t0 + 0.1 * max(n_raw - 1, 0),
        mode=mode,  # type: ignore[arg-type]
        raw=raw,
    )


def random_joints(rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 6) joint angles [deg] inside :data:`JOINT_RANGE_DEG`."""
    lo, hi = JOINT_RANGE_DEG[:, 0], JOINT_RANGE_DEG[:, 1]
    return np.asarray(lo + rng.random((n, 6)) * (hi - lo))


def csv_text(n: int, seed: int = 0, *, groups: bool = False) -> str:
    """A valid samples CSV with ``n`` rows (3 decimals), anchors A/B, optional groups."""
    rng = np.random.default_rng(seed)
    q = random_joints(rng, n)
    length = 300.0 + rng.random(n) * 1500.0
    lines = ["q1,q2,q3,q4,q5,q6,L,anchor" + (",group" if groups else "")]
    for i in range(n):
        cells = [f"{v:.3f}" for v in q[i]] + [f"{length[i]:.3f}", "AB"[i % 2]]
        if groups:
            cells.append(f"g{i // 4}")
        lines.append(",".join(cells))
    return "\n".join(lines) + "\n"


def replace_cell(text: str, line_no: int, column: int, value: str) -> str:
    """``text`` with the cell at file line ``line_no`` (header = 1), column index replaced."""
    lines = text.splitlines()
    cells = lines[line_no - 1].split(",")
    cells[column] = value
    lines[line_no - 1] = ",".join(cells)
    return "\n".join(lines) + "\n"


def sample_count(path: Path) -> int:
    """Rows in ``samples``, through an independent connection."""
    with sqlite3.connect(path) as conn:
        return int(conn.execute("SELECT count(*) FROM samples").fetchone()[0])


def import_csv(store: Store, campaign_id: int, text: str) -> list[int]:
    """Parse CSV text and import it, as the import route does."""
    return store.import_samples(campaign_id, parse_samples_csv(text))


def fake_result(offset_mm: float) -> dict[str, Any]:
    """The parts of :meth:`IdentifyResult.to_json` the store reads, plus a NaN metric
    (what ``to_json`` gives for the test figures of a run with ``test_fraction=0``)."""
    dh = [
        {"joint": j + 1, "alpha_deg": 0.0, "a_mm": 100.0 + offset_mm, "d_mm": 0.0, "theta_deg": 0.0}
        for j in range(6)
    ]
    figures = {"rmse_mm": 0.1 + offset_mm, "mae_mm": 0.08, "std_mm": 0.1, "max_mm": 0.3}
    return {
        "robot": ROBOT,
        "method": "ukf-vslm",
        "convention": "dh",
        "dh": dh,
        "tool_mm": [0.0, 0.0, 50.0 + offset_mm],
        "metrics": {
            "before": {"train": figures, "test": {**figures, "rmse_mm": math.nan}},
            "after": {"train": figures, "test": figures},
        },
    }
