"""How many included samples a campaign needs before an identification is accepted.

The rule is calib's, applied on ``POST /campaigns/{id}/identifications``
(:func:`calib.options.validate`): the training rows that ``test_fraction`` leaves must pass
:func:`calib.options.check_training_rows` for the parameters identify can solve,
:func:`calib.identifiability.max_solved`. That count depends on the robot model and the
number of anchors (each further anchor adds its P0 and offset, 4 parameters), so the page
cannot hard-code it: the campaign JSON carries it (``min_samples_to_identify`` at the
default options, and ``min_training_samples`` for another test fraction), and the count
recommended (``recommended_samples``): the one at which ``robust auto`` can screen outliers
(:func:`calib.options.training_rows_recommended`).

Nothing here restates calib's rule: the parameter count is
:func:`calib.options.parameters_to_solve`, the training rows it needs
:func:`calib.options.training_rows_needed` (recommended:
:func:`calib.options.training_rows_recommended`), and the samples whose training part reaches
that :func:`calib.options.samples_for_training_rows`. ``max_solved`` costs one Jacobian at 200
poses, so :class:`MinSamplesCache` keeps each answer per (robot id, number of anchors):
``GET /campaigns`` is polled by the page.
"""

from __future__ import annotations

import string
import threading
from dataclasses import dataclass

from calib.models import RobotModel
from calib.options import (
    IdentifyOptions,
    parameters_to_solve,
    samples_for_training_rows,
    training_rows_needed,
    training_rows_recommended,
)
from daemon.store import Store


@dataclass(frozen=True)
class MinSamples:
    """What identify needs for one robot and anchor count, at ``test_fraction``.

    Attributes
    ----------
    n_params : int
        The most parameters identify solves (:func:`calib.identifiability.max_solved`).
    training_samples : int
        The fewest training rows :func:`calib.options.check_training_rows` accepts
        (:func:`calib.options.training_rows_needed`).
    samples : int
        The fewest included samples whose training part (``n - round(test_fraction * n)``,
        the random hold-out of :func:`calib.options.validate`) is enough.
    test_fraction : float
    recommended_training_samples : int
        The training rows at which ``robust auto`` screens outliers
        (:func:`calib.options.training_rows_recommended`).
    recommended_samples : int
        The included samples whose training part reaches that.
    """

    n_params: int
    training_samples: int
    samples: int
    test_fraction: float
    recommended_training_samples: int = 0
    recommended_samples: int = 0


def anchor_ids(n_anchors: int) -> tuple[str, ...]:
    """``n_anchors`` distinct anchor ids (A, B, … then A1, B1, …): only their number matters
    to the count (the layout names, never the values, depend on them)."""
    letters = string.ascii_uppercase
    return tuple(
        letters[k % 26] + (str(k // 26) if k >= 26 else "") for k in range(max(n_anchors, 1))
    )


def min_samples(
    model: RobotModel, n_anchors: int, options: IdentifyOptions | None = None
) -> MinSamples:
    """The fewest samples identify accepts for ``model`` with ``n_anchors`` anchors (0 counts
    as 1: the first capture brings one) and ``options`` (default: the defaults of
    :class:`calib.options.IdentifyOptions`, as a job submitted without options).

    Raises
    ------
    ValueError
        ``n_anchors`` negative, or ``options`` name a parameter the layout does not have.
    """
    if n_anchors < 0:
        raise ValueError(f"n_anchors: must be >= 0, got {n_anchors}")
    opts = options if options is not None else IdentifyOptions()
    n_params = parameters_to_solve(model, anchor_ids(n_anchors), opts)
    need = training_rows_needed(n_params)
    recommended = training_rows_recommended(n_params)
    tf = opts.test_fraction
    return MinSamples(
        n_params=n_params,
        training_samples=need,
        samples=samples_for_training_rows(need, tf),
        test_fraction=tf,
        recommended_training_samples=recommended,
        recommended_samples=samples_for_training_rows(recommended, tf),
    )


def held_out(n: int, test_fraction: float) -> int:
    """Rows of ``n`` held out to test: ``round(test_fraction * n)`` (Python's rounding), as
    :func:`calib.options.validate` and :func:`calib.split.split_rows` count them."""
    return round(test_fraction * n)


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
