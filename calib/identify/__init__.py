"""Identification of a robot's DH errors, tool point, anchors and zero offsets from cable lengths.

The package's steps are its modules; :mod:`calib.identify.run` runs them in order. Callers
import the public API from here.
"""

from __future__ import annotations

from calib.identify.run import (
    METHODS,
    IdentifyOptions,
    IdentifyResult,
    identify,
    identify_checked,
    pose_groups,
    split_rows,
)

__all__ = [
    "METHODS",
    "IdentifyOptions",
    "IdentifyResult",
    "identify",
    "identify_checked",
    "pose_groups",
    "split_rows",
]
