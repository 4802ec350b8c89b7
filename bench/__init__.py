"""Benchmarks (``make bench``): run as ``python -m bench.NAME``; each writes its results here."""

from daemon.process.blas import single_threaded_blas, steady_heap

single_threaded_blas()  # measure the product as the cablecal command runs it (daemon.process.blas)
steady_heap()
