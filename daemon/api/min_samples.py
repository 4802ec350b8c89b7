"""The daemon's cache of :func:`calib.min_samples.min_samples`, per robot and anchor count.

``max_solved`` costs one Jacobian at 200 poses, so :class:`MinSamplesCache` keeps each answer
per (robot id, number of anchors): ``GET /campaigns`` is polled by the page. The rule itself
is calib's (:mod:`calib.min_samples`).
"""

from __future__ import annotations

import threading

from calib.min_samples import MinSamples, min_samples
from daemon.store import Store


class MinSamplesCache:
    """:func:`min_samples` at the default options per (robot id, number of anchors) of one
    store. A robot row never changes once written, so an answer never goes stale.
    Thread-safe (the sync routes run in a thread pool); two threads may compute the same
    answer once each."""

    def __init__(self, store: Store) -> None:
        self.store = store
        self._lock = threading.Lock()
        self._cache: dict[tuple[int, int], MinSamples] = {}

    def get(self, robot_id: int, n_anchors: int) -> MinSamples:
        """The answer for robot ``robot_id`` (its stored nominal model) and ``n_anchors``.

        Raises
        ------
        daemon.store.StoreNotFound
            No such robot.
        """
        key = (robot_id, max(n_anchors, 1))
        with self._lock:
            hit = self._cache.get(key)
        if hit is not None:
            return hit
        found = min_samples(self.store.robot_model(robot_id), key[1])
        with self._lock:
            self._cache[key] = found
        return found
