"""Helpers of the brand-face tests (KUKA VarProxy, FANUC RMI): a face started on an
emulated cell's loop, and how far a joint reading is from the cell's truth."""

from __future__ import annotations

import asyncio
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from typing import TypeVar

import numpy as np

from simulator.cell import EmulatedCell
from simulator.runner import SimulatorThread
from simulator.servers import TcpServer

Face = TypeVar("Face", bound=TcpServer)


@contextmanager
def face_on(sim: SimulatorThread, make: Callable[[EmulatedCell], Face]) -> Iterator[Face]:
    """A face built by ``make(cell)`` started on ``sim``'s event loop, stopped after."""
    face = make(sim.cell)
    asyncio.run_coroutine_threadsafe(face.start(), sim.loop).result(timeout=5)
    try:
        yield face
    finally:
        asyncio.run_coroutine_threadsafe(face.stop(), sim.loop).result(timeout=5)


def link_down(sim: SimulatorThread, face: TcpServer, duration_s: float) -> None:
    """Take ``face`` away for ``duration_s`` (returns once it is down)."""
    asyncio.run_coroutine_threadsafe(_down(face, duration_s), sim.loop).result(timeout=5)


async def _down(face: TcpServer, duration_s: float) -> None:
    task = asyncio.ensure_future(face.link_down(duration_s))
    _TASKS.add(task)
    task.add_done_callback(_TASKS.discard)
    await asyncio.sleep(0.05)


_TASKS: set[asyncio.Future[None]] = set()


def deviation_from_truth_deg(
    sim: SimulatorThread, joints_deg: Sequence[float], t_from_s: float, t_to_s: float
) -> float:
    """``min_t max_j |q_j(t) - reading_j|`` [deg] for t in [t_from_s, t_to_s] (monotonic
    seconds): how far a reading is from the cell's truth at any instant of that span (0.5 ms
    grid, then 0.01 ms around the best instant)."""
    reading = np.asarray(joints_deg, dtype=float)

    def best(times_s: np.ndarray) -> tuple[float, float]:
        devs = [float(np.abs(sim.cell.reported_joints(t) - reading).max()) for t in times_s]
        k = int(np.argmin(devs))
        return float(times_s[k]), devs[k]

    t_best, _ = best(np.arange(t_from_s - 0.001, t_to_s + 0.0005, 0.0005))
    return best(np.arange(t_best - 0.0006, t_best + 0.0006, 0.00001))[1]


def last_tx_s(frames: Sequence[str]) -> float:
    """Monotonic time [s] of the last frame sent, from a driver's frame log."""
    return max(float(line.split()[0]) for line in frames if " tx " in line)
