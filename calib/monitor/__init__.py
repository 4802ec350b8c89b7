"""Numeric decisions of the daemon's monitors, pure (no I/O, no clock, no asyncio).

- :mod:`calib.monitor.settle`: is the robot still and the length steady (a capture window)?
- :mod:`calib.monitor.stepwatch`: did the drawstring sensor move (a step in the residuals)?
- :mod:`calib.monitor.running_fit`: the live watch's running fit of a campaign, and its
  per-sample test (:class:`calib.monitor.running_fit.LiveTester`).
- :mod:`calib.monitor.holdcheck`: does a calibrated robot still hold its calibration (a
  hold check, the daemon's ``hold_check``; not :mod:`calib.drift`, the measurement drifting
  within one campaign)?

The daemon (:mod:`daemon.monitors.watch`, :mod:`daemon.monitors.holdcheck`, the sampler) owns the
I/O, the time and the state around them.
"""
