"""The daemon's process plumbing: one BLAS thread and a steady heap before numpy loads
(:mod:`daemon.process.blas`), the set-up of every child process and the forkserver's guard
(:mod:`daemon.process.workers`, :mod:`daemon.process.forkserver_guard`), logging
(:mod:`daemon.process.logs`), sd_notify and the watchdog (:mod:`daemon.process.notify`) and
the start and stop events (:mod:`daemon.process.lifecycle`). This package module imports
nothing: ``cablecal`` imports :mod:`daemon.process.blas` before anything else."""
