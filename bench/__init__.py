"""Benchmarks (``make bench``): run as ``python -m bench.NAME``; each writes its results here."""

from daemon.blas import single_threaded_blas

single_threaded_blas()  # measure the product as the cablecal command runs it (daemon.blas)
