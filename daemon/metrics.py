"""Prometheus metrics of the daemon, on a registry of our own (served at ``GET /metrics``).

Every part of the daemon imports its instruments from here, so the names live in one place.
Label values are bounded: device names come from configuration, reasons and outcomes from fixed
sets, routes are the path templates (not the raw URLs).
"""

from __future__ import annotations

from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram

REGISTRY = CollectorRegistry(auto_describe=True)

DEVICE_POLLS = Counter(
    "cablecal_device_polls",
    "Device polls that returned a valid reading.",
    ["device", "role"],  # role: indicator | robot
    registry=REGISTRY,
)
DEVICE_ERRORS = Counter(
    "cablecal_device_errors",
    "Device polls that failed, by error class (IndicatorCRCError, RobotLinkDown, ...).",
    ["device", "role", "error"],
    registry=REGISTRY,
)
DEVICE_RECONNECTS = Counter(
    "cablecal_device_reconnects",
    "Times a device delivered again after a failure.",
    ["device", "role"],
    registry=REGISTRY,
)
LAST_READING_AGE = Gauge(
    "cablecal_last_reading_age_seconds",
    "Age of the device's last valid reading at scrape time [s].",
    ["device", "role"],
    registry=REGISTRY,
)
CAPTURES = Counter(
    "cablecal_captures",
    "Capture attempts by outcome; reason is 'ok' for accepted ones.",
    ["outcome", "reason", "mode"],  # outcome: accepted | rejected | failed (not stored)
    registry=REGISTRY,
)
ROBOT_LATE = Counter(
    "cablecal_robot_late",
    "Episodes in which a robot that answers had no joint reading newer than the settle window "
    "(settle_s): its replies come late, so no window can settle (daemon.sampler.late).",
    ["device"],
    registry=REGISTRY,
)
POSES_LOST = Counter(
    "cablecal_poses_lost",
    "Auto mode: poses the robot stood still at and left without a capture or a recorded "
    "rejection, by why no window settled there (robot_late, stale, moving, over_range, ...).",
    ["reason"],
    registry=REGISTRY,
)
JOBS = Counter(
    "cablecal_identification_jobs",
    "Finished identification jobs by method and final status.",
    ["method", "status"],
    registry=REGISTRY,
)
JOB_DURATION = Histogram(
    "cablecal_identification_job_duration_seconds",
    "Wall time of identification jobs from start to finish [s].",
    ["method", "status"],
    buckets=(0.05, 0.1, 0.25, 0.5, 1, 2.5, 5, 10, 30, 60, 120, 300),
    registry=REGISTRY,
)
HTTP_LATENCY = Histogram(
    "cablecal_http_request_duration_seconds",
    "API request latency by route template and status code [s].",
    ["method", "route", "status"],
    buckets=(0.001, 0.0025, 0.005, 0.01, 0.02, 0.05, 0.1, 0.25, 0.5, 1, 2.5),
    registry=REGISTRY,
)
#: The names the hold-check gauges had before 0.2.0, exported as well until 0.3.0 removes
#: them (CHANGELOG): dashboards and alert rules move to the ``cablecal_hold_check_*`` names.
DEPRECATED_HOLD_CHECK_NAMES = {
    "cablecal_hold_check_rms_mm": "cablecal_drift_rms_mm",
    "cablecal_hold_check_threshold_mm": "cablecal_drift_threshold_mm",
}
_HOLD_CHECK_HELP = {
    "cablecal_hold_check_rms_mm": "RMS cable-length residual of the robot's last hold check "
    "against its calibration [mm].",
    "cablecal_hold_check_threshold_mm": "Threshold of the robot's last hold check: above it "
    "the robot no longer holds its calibration [mm].",
}
HOLD_CHECK_GAUGES = {
    name: (
        Gauge(name, text, ["robot"], registry=REGISTRY),  # robot id
        Gauge(
            DEPRECATED_HOLD_CHECK_NAMES[name],
            f"Deprecated (removed in 0.3.0): {name}. {text}",
            ["robot"],
            registry=REGISTRY,
        ),
    )
    for name, text in _HOLD_CHECK_HELP.items()
}


def record_hold_check(robot_id: int, rms_mm: float, threshold_mm: float) -> None:
    """A finished hold check's RMS and threshold [mm] on the robot's gauges, under their
    names and their deprecated names."""
    values = {
        "cablecal_hold_check_rms_mm": rms_mm,
        "cablecal_hold_check_threshold_mm": threshold_mm,
    }
    for name, value in values.items():
        for gauge in HOLD_CHECK_GAUGES[name]:
            gauge.labels(str(robot_id)).set(value)


SENSOR_MOVED = Counter(
    "cablecal_sensor_moved",
    "Moves of the drawstring sensor found by the live watch (daemon.monitors.watch), per robot.",
    ["robot"],  # robot id
    registry=REGISTRY,
)
IDENTIFICATIONS_FAILED = Counter(
    "cablecal_identifications_failed",
    "Identification jobs that failed (an error or a timeout; cancelled ones are not).",
    registry=REGISTRY,
)
UNCLEAN_SHUTDOWNS = Counter(
    "cablecal_unclean_shutdowns",
    "Runs of the daemon that ended without their shutdown, as recorded in the store (the "
    "count carries over restarts, so increase() sees a new one).",
    registry=REGISTRY,
)
