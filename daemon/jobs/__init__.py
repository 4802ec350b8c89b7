"""Identification jobs: the manager in the daemon (:mod:`daemon.jobs.manager`: the process
pool, progress, cancel, restart safety), the worker side that runs in the pool
(:mod:`daemon.jobs.worker`) and the plan check a succeeded result gets
(:mod:`daemon.jobs.plan_check`). This package module re-exports nothing."""
