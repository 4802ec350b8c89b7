"""One BLAS thread per process, set before numpy loads its BLAS.

The matrices cablecal works on are small: a Jacobian of at most a few thousand rows by about 31
columns. On the 2-core PCs a cell runs on, OpenBLAS's worker threads (one per core by default)
spin against the sampler, the service and each other, and a thin SVD gets slower, not faster
(the figures: bench/design_figures.md).

:func:`single_threaded_blas` only sets the variables that are not set already, so an operator
can still choose (``OPENBLAS_NUM_THREADS=2 cablecal identify …``). It must run before the first
``import numpy`` of the process; child processes inherit the environment. Standard library only.
"""

from __future__ import annotations

import os

#: The thread-count variables of OpenBLAS, OpenMP (and so a BLAS built on it) and MKL.
BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def single_threaded_blas() -> None:
    """Default every BLAS thread-count variable to 1 (those already set are kept)."""
    for name in BLAS_THREAD_VARIABLES:
        os.environ.setdefault(name, "1")
