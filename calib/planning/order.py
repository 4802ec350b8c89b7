"""Ordering planned poses to shorten a campaign, and its estimated duration.

Travel between two poses is timed as a synchronous joint move: every joint runs at its own
speed, so a move takes ``max_j |Δq_j| / v_j`` seconds (acceleration ignored). The open path
through the poses is built by nearest neighbour from every possible first pose (the shortest
kept), then improved by 2-opt (reverse a segment when that shortens the path) until no reversal
helps. The travel time is symmetric, so reversing a segment leaves its inner moves unchanged
and a 2-opt move is judged by its two end moves alone.
"""

from __future__ import annotations

import itertools

import numpy as np

from calib.kinematics import FloatArray


def travel_time_matrix(q_deg: FloatArray, speed_deg_s: FloatArray) -> FloatArray:
    """Move times between every pair of poses, shape (n, n) [s], for poses (n, 6) [deg]."""
    diff = np.abs(q_deg[:, None, :] - q_deg[None, :, :]) / np.asarray(speed_deg_s)
    out: FloatArray = diff.max(axis=2)
    return out


def _path_length(dist: FloatArray, path: list[int]) -> float:
    return float(sum(dist[a, b] for a, b in itertools.pairwise(path)))


def _nearest_neighbour(dist: FloatArray, first: int) -> list[int]:
    n = dist.shape[0]
    seen = np.zeros(n, dtype=bool)
    path = [first]
    seen[first] = True
    for _ in range(n - 1):
        row = np.where(seen, np.inf, dist[path[-1]])
        nxt = int(np.argmin(row))
        path.append(nxt)
        seen[nxt] = True
    return path


def _two_opt(dist: FloatArray, path: list[int], max_passes: int = 50) -> list[int]:
    p = np.array(path)
    n = p.size
    for _ in range(max_passes):
        improved = False
        for i in range(n - 1):
            # Reverse p[i+1 .. j]: moves (p[i], p[i+1]) and (p[j], p[j+1]) become
            # (p[i], p[j]) and (p[i+1], p[j+1]); j = n-1 has no outgoing move.
            j = np.arange(i + 2, n)
            if j.size == 0:
                continue
            nxt = np.append(p[j[:-1] + 1], -1)
            old = dist[p[i], p[i + 1]] + np.where(nxt >= 0, dist[p[j], nxt], 0.0)
            new = dist[p[i], p[j]] + np.where(nxt >= 0, dist[p[i + 1], nxt], 0.0)
            gain = old - new
            best = int(np.argmax(gain))
            if gain[best] > 1e-9:
                jj = int(j[best])
                p[i + 1 : jj + 1] = p[i + 1 : jj + 1][::-1].copy()
                improved = True
        if not improved:
            break
    return [int(v) for v in p]


def order_poses(q_deg: FloatArray, speed_deg_s: FloatArray) -> tuple[list[int], float]:
    """A short open path through the poses: nearest neighbour (best start) plus 2-opt.

    Parameters
    ----------
    q_deg : ndarray, shape (n, 6)
    speed_deg_s : ndarray, shape (6,)

    Returns
    -------
    order : list of int
        Indices into ``q_deg``.
    travel_s : float
        Total move time along it [s].
    """
    n = q_deg.shape[0]
    if n <= 1:
        return list(range(n)), 0.0
    dist = travel_time_matrix(q_deg, speed_deg_s)
    best: list[int] = []
    best_len = np.inf
    for first in range(n):
        path = _nearest_neighbour(dist, first)
        length = _path_length(dist, path)
        if length < best_len:
            best, best_len = path, length
    path = _two_opt(dist, best)
    return path, _path_length(dist, path)


def campaign_time_s(q_deg: FloatArray, speed_deg_s: FloatArray, dwell_s: float) -> float:
    """Duration of visiting the poses in the given order: moves plus ``dwell_s`` per pose [s]."""
    if q_deg.shape[0] == 0:
        return 0.0
    moves = np.abs(np.diff(q_deg, axis=0)) / np.asarray(speed_deg_s)
    return float(moves.max(axis=1).sum() + dwell_s * q_deg.shape[0])
