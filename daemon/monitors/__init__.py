"""The daemon's live monitors, started by the lifespan after the sampler: the sensor watch
(:mod:`daemon.monitors.watch`), the hold check (:mod:`daemon.monitors.holdcheck`) and auto
capture's one owner (:mod:`daemon.monitors.autocapture`). Their pure decisions are calib's
(:mod:`calib.monitor`). This package module re-exports nothing."""
