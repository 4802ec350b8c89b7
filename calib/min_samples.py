"""How many included samples a campaign needs before an identification is accepted.

The rule is :func:`calib.options.validate`'s: the training rows that ``test_fraction`` leaves
must pass :func:`calib.options.check_training_rows` for the parameters identify can solve,
:func:`calib.identifiability.max_solved`. That count depends on the robot model and the
number of anchors (each further anchor adds its P0 and offset, 4 parameters), so the page
cannot hard-code it: the daemon's campaign JSON carries it (``min_samples_to_identify`` at
the default options, and ``min_training_samples`` for another test fraction), and the count
recommended (``recommended_samples``): the one at which ``robust auto`` can screen outliers
(:func:`calib.options.training_rows_recommended`).

Nothing here restates the rule: the parameter count is
:func:`calib.options.parameters_to_solve`, the training rows it needs
:func:`calib.options.training_rows_needed` (recommended:
:func:`calib.options.training_rows_recommended`), and the samples whose training part reaches
that :func:`calib.options.samples_for_training_rows` (hold-out:
:func:`calib.options.held_out`). ``max_solved`` costs one Jacobian at 200 poses, so the
daemon keeps each answer (:class:`daemon.api.min_samples.MinSamplesCache`).
"""

from __future__ import annotations

import string
from dataclasses import dataclass

from calib.models import RobotModel
from calib.options import (
    IdentifyOptions,
    parameters_to_solve,
    samples_for_training_rows,
    training_rows_needed,
    training_rows_recommended,
)


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
        The fewest included samples whose training part (``n - held_out(n, test_fraction)``,
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
