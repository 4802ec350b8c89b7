"""Training and test rows: random rows, or whole pose groups (the ``holdout`` option)."""

from __future__ import annotations

import numpy as np

from calib.dataset import SampleSet
from calib.options import Holdout, held_out


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
