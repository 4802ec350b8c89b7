"""Training and test rows: random rows, or whole pose groups (the ``holdout`` option); and
:func:`check`, the options checked once on the split identify runs on (:class:`Checked`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from calib.dataset import SampleSet
from calib.options import Holdout, IdentifyOptions, SplitOptions, held_out, part, validate

if TYPE_CHECKING:
    from calib.models import RobotModel


def pose_groups(samples: SampleSet, n_groups: int) -> np.ndarray:
    """Group label per sample, shape (n,): the ``group`` column, or Ward clusters of joints."""
    if samples.group is not None:
        ids = {g: i for i, g in enumerate(dict.fromkeys(samples.group))}
        return np.array([ids[g] for g in samples.group], dtype=int)
    n = len(samples)
    if n <= n_groups:
        return np.arange(n)
    # Imported here: scipy.cluster costs import time on every path that reads calib (CLI help).
    import scipy.cluster.hierarchy as sch

    tree = sch.linkage(samples.joints_deg, method="ward")
    return np.asarray(sch.fcluster(tree, t=n_groups, criterion="maxclust"), dtype=int) - 1


def split_rows(
    samples: SampleSet, test_fraction: float, seed: int, holdout: Holdout, n_groups: int = 10
) -> tuple[np.ndarray, np.ndarray]:
    """Training and test row indices (sorted), shapes (n_train,) and (n_test,)."""
    n = len(samples)
    rng = np.random.default_rng(seed)
    if test_fraction <= 0:
        return np.arange(n), np.zeros(0, dtype=int)
    target = held_out(n, test_fraction)
    if holdout == "random":
        perm = rng.permutation(n)
        return np.sort(perm[target:]), np.sort(perm[:target])
    labels = pose_groups(samples, n_groups)
    test: list[int] = []
    for g in rng.permutation(np.unique(labels)):
        if len(test) >= target:
            break
        test.extend(np.flatnonzero(labels == g).tolist())
    test_rows = np.sort(np.array(test, dtype=int))
    train_rows = np.setdiff1d(np.arange(n), test_rows)
    return train_rows, test_rows


@dataclass(frozen=True)
class Checked:
    """Options checked once against a sample set and a robot (:func:`check`), with the split
    identify trains and tests on: :func:`calib.identify.identify_checked` runs on it without
    checking the options again (the daemon checks a job when it is submitted and hands this
    to the worker)."""

    options: IdentifyOptions
    train_rows: np.ndarray  # (n_train,) row indices
    test_rows: np.ndarray  # (n_test,) row indices


def check(
    model: RobotModel,
    samples: SampleSet,
    options: IdentifyOptions | None = None,
    train_rows: np.ndarray | None = None,
    test_rows: np.ndarray | None = None,
) -> Checked:
    """Step 1's one check of the options: split the rows (random, grouped, or the given
    ``train_rows``/``test_rows``; :func:`split_rows`) and check the options against the
    samples and the robot on that split (:func:`calib.options.validate`).

    Raises
    ------
    SampleError, calib.options.OptionError
        As :func:`calib.options.validate`.
    """
    opts = options or IdentifyOptions()
    if train_rows is None or test_rows is None:
        split = part(opts, SplitOptions)
        train_rows, test_rows = split_rows(
            samples, split.test_fraction, split.seed, split.holdout, split.n_groups
        )
    validate(samples, opts, train_rows, model=model)
    return Checked(opts, train_rows, test_rows)
