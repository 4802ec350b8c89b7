"""Pose planning: which poses to measure, and what accuracy they will give.

See :mod:`calib.planning.planner` for the method; :func:`plan` is the entry point. The names
below load on first use (PEP 562), so :mod:`calib.planning.options` (standard library only)
is read without numpy, as ``cablecal plan --help`` does for its defaults. (No submodule is
named like an exported function, so importing one never shadows a name here.)
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from calib.planning.options import PlanOptions
    from calib.planning.planner import evaluate_poses, plan
    from calib.planning.result import CSV_COLUMNS, PlanResult
    from calib.planning.start import start_anchors_mm

#: Where each exported name lives.
_HOMES = {
    "PlanOptions": "calib.planning.options",
    "evaluate_poses": "calib.planning.planner",
    "plan": "calib.planning.planner",
    "start_anchors_mm": "calib.planning.start",
    "CSV_COLUMNS": "calib.planning.result",
    "PlanResult": "calib.planning.result",
}


def __getattr__(name: str) -> Any:
    home = _HOMES.get(name)
    if home is None:
        raise AttributeError(f"module 'calib.planning' has no attribute {name!r}")
    value = getattr(importlib.import_module(home), name)
    globals()[name] = value
    return value


__all__ = ["CSV_COLUMNS", "PlanOptions", "PlanResult", "evaluate_poses", "plan", "start_anchors_mm"]
