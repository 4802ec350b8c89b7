"""One BLAS thread per process, set before numpy loads its BLAS.

The matrices cablecal works on are small: a Jacobian of at most a few thousand rows by about 31
columns. On the 2-core PCs a cell runs on, OpenBLAS's worker threads (one per core by default)
spin against the sampler, the service and each other, and a thin SVD gets slower, not faster
(the figures: bench/design_figures.md).

:func:`single_threaded_blas` only sets the variables that are not set already, so an operator
can still choose (``OPENBLAS_NUM_THREADS=2 cablecal identify …``). It must run before the first
``import numpy`` of the process; child processes inherit the environment. Standard library only.

:func:`steady_heap` is the other half of a numeric process's set-up: glibc's malloc serves a
block above its mmap threshold (128 KiB at start) by mapping fresh pages, and raises the
threshold only as such blocks are freed. A Jacobian of 2000 rows is 0.5 MB, so a process's
first identification maps, faults in and unmaps its temporaries again and again until the
threshold has grown; fixing the thresholds at once lets the heap reuse those pages from the
first call (the figures: bench/cli_speed.md).
"""

from __future__ import annotations

import os
import sys

#: The thread-count variables of OpenBLAS, OpenMP (and so a BLAS built on it) and MKL.
BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def single_threaded_blas() -> None:
    """Default every BLAS thread-count variable to 1 (those already set are kept)."""
    for name in BLAS_THREAD_VARIABLES:
        os.environ.setdefault(name, "1")


#: glibc's ``mallopt`` parameters (malloc.h) and the values :func:`steady_heap` sets [bytes]:
#: blocks below 32 MiB come from the heap, and up to 64 MiB freed at its top is kept.
M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3
MMAP_THRESHOLD_BYTES = 32 << 20
TRIM_THRESHOLD_BYTES = 64 << 20


def steady_heap() -> bool:
    """Fix glibc's mmap and trim thresholds (see the module docstring); False where the C
    library has no ``mallopt`` (not Linux, or not glibc) or refuses, and nothing changes."""
    if not sys.platform.startswith("linux"):
        return False
    import ctypes  # lazily: only where it can apply

    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = [ctypes.c_int, ctypes.c_int], ctypes.c_int
    ok = int(mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)) == 1
    return ok and int(mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD_BYTES)) == 1
