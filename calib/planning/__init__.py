"""Pose planning: which poses to measure, and what accuracy they will give.

See :mod:`calib.planning.plan` for the method; :func:`plan` is the entry point.
"""

from calib.planning.options import PlanOptions
from calib.planning.plan import evaluate_poses, plan, start_anchors_mm
from calib.planning.result import CSV_COLUMNS, PlanResult

__all__ = ["CSV_COLUMNS", "PlanOptions", "PlanResult", "evaluate_poses", "plan", "start_anchors_mm"]
