"""The paper's evaluation protocol (Table VIII), drawn in one place.

Per seed ``s``, ``n_train + n_test`` rows (100 + 20 in the paper) are drawn at random from the
data (``numpy.random.default_rng(s).permutation``), the first ``n_train`` to train and the rest
to test, and every method is identified on that same draw with default options (``seed = s``,
maximum likelihood unless ``prior``). ``cablecal compare`` and ``bench/real_data.py`` both run
it from here, so their figures come from the same draws.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from calib.dataset import SampleSet
from calib.models import RobotModel
from calib.options import (
    METHODS,
    PAPER_N_TEST,
    PAPER_N_TRAIN,
    OptionError,
    options_from_mapping,
)
from calib.timing import Clock, Timer

if TYPE_CHECKING:
    from calib.identify import IdentifyResult


def paper_split(
    n: int, seed: int, n_train: int = PAPER_N_TRAIN, n_test: int = PAPER_N_TEST
) -> tuple[np.ndarray, np.ndarray]:
    """Sorted training and test rows of one draw, shapes (n_train,) and (n_test,), of ``n``."""
    pick = np.random.default_rng(seed).permutation(n)[: n_train + n_test]
    return np.sort(pick[:n_train]), np.sort(pick[n_train:])


@dataclass(frozen=True)
class ProtocolRun:
    """One identification of the protocol: seed, method, result and wall time [s]."""

    seed: int
    method: str
    result: IdentifyResult
    elapsed_s: float


def check_protocol(samples: SampleSet, methods: Sequence[str], n_train: int, n_test: int) -> None:
    """Raise :class:`calib.options.OptionError` for an unknown method, ``n_train < 1``, or more
    rows asked for than the data have."""
    bad = [m for m in methods if m not in METHODS]
    if bad:
        raise OptionError("methods", f"unknown {bad}; known {list(METHODS)}")
    if n_train < 1:
        raise OptionError("n_train", f"must be positive; got {n_train}")
    if n_train + n_test > len(samples):
        raise OptionError(
            "n_train", f"n_train + n_test = {n_train + n_test} > {len(samples)} samples"
        )


def run_protocol(
    model: RobotModel,
    samples: SampleSet,
    methods: Sequence[str],
    seeds: Sequence[int],
    n_train: int = PAPER_N_TRAIN,
    n_test: int = PAPER_N_TEST,
    prior: bool = False,
    clock: Clock | None = None,
) -> Iterator[ProtocolRun]:
    """Identify with every method on every seed's draw; yields the runs seed by seed.

    Call :func:`check_protocol` first to fail before anything runs. ``clock``
    (:data:`calib.timing.Clock`, injected by the caller) times each run and its
    identification's ``elapsed_s``; None: 0.
    """
    from calib.identify import identify  # the solvers and scipy: not on the CLI's --help path

    check_protocol(samples, methods, n_train, n_test)
    for s in seeds:
        train, test = paper_split(len(samples), s, n_train, n_test)
        for m in methods:
            opts = options_from_mapping({"method": m, "seed": s, "prior": prior})
            timer = Timer(clock)
            res = identify(model, samples, opts, train_rows=train, test_rows=test, clock=clock)
            yield ProtocolRun(s, m, res, timer.elapsed())
