"""The program formats' names, file suffixes and the default dwell: their one home.

Standard library only and nothing imported from the writers, so the command line builds its
``--format`` choice from here without loading them (``cablecal --help`` stays light).
"""

from __future__ import annotations

#: Controller program formats, in the order the CLI, the REST enum and the page list them.
PROGRAM_FORMATS: tuple[str, ...] = ("rapid", "urscript", "krl", "fanuc-ls")

#: What ``GET /campaigns/{id}/plan?format=`` and the compensated-target download serve.
DOWNLOAD_FORMATS: tuple[str, ...] = ("csv", *PROGRAM_FORMATS)

#: File suffix per format (Fanuc's controller file names are upper case).
SUFFIX: dict[str, str] = {
    "csv": ".csv",
    "rapid": ".mod",
    "urscript": ".script",
    "krl": ".src",
    "fanuc-ls": ".LS",
}

#: What each format is, for help texts and the page.
TITLE: dict[str, str] = {
    "csv": "joint-target CSV",
    "rapid": "ABB RAPID module",
    "urscript": "UR URScript",
    "krl": "KUKA KRL",
    "fanuc-ls": "Fanuc TP (ASCII)",
}

#: The robot maker whose controllers run each format (the robot library's ``# maker:`` words,
#: lower case: :func:`calib.robots.files.library_info`): the filter warns when a program's
#: format is not the robot's maker's.
MAKER: dict[str, str] = {
    "rapid": "abb",
    "urscript": "ur",
    "krl": "kuka",
    "fanuc-ls": "fanuc",
}

#: Default joint speed of a program [% of the robot's maximum]: calm moves, short campaign.
DEFAULT_SPEED_PCT = 25.0

#: Settle windows in a dwell: one for the arm to stop ringing after the fine stop, one for
#: the sampler to see it still (``settle_s``), one spare for a slow poll or a retried read.
DWELL_SETTLE_WINDOWS = 3
#: Added to the dwell for the capture itself (average, store) [s].
DWELL_MARGIN_S = 0.5


def dwell_s_for_settle(settle_s: float) -> float:
    """Default dwell at each pose [s] for a sampler settle window ``settle_s`` [s]:
    :data:`DWELL_SETTLE_WINDOWS` windows plus :data:`DWELL_MARGIN_S`, rounded up to 0.1 s."""
    if not settle_s > 0:
        raise ValueError(f"settle_s: must be > 0, got {settle_s}")
    tenths = DWELL_SETTLE_WINDOWS * settle_s * 10 + DWELL_MARGIN_S * 10
    return float(-(-round(tenths, 6) // 1)) / 10
