"""UR's branch rule: a target's nominal solution is the one nearest its joint reference
(``qnear``, PolyScope's ``Waypoint_n_q``, or the previous move's joints), and a corrected pose
must still solve to it from that reference (docs/compensation.md, "Universal Robots")."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from calib.filter.branches import closed_form_is_complete, nominal_solutions
from calib.filter.kin import solve_flange_ik
from calib.filter.select import choose_nearest
from calib.ik import IKOptions
from calib.kinematics import FloatArray
from calib.models import RobotModel
from calib.tcp import joint_limits_deg

#: IK of the calibrated model: tight tolerances (the rounding of the written numbers, not the
#: IK, should limit the result).
IK_OPTIONS = IKOptions(max_iterations=60, tol_mm=1e-6, tol_deg=1e-6, stall_iterations=8)


def nearest_solutions(
    nominal: RobotModel, fl: FloatArray, refs: FloatArray
) -> tuple[list[FloatArray], list[str]]:
    """UR's rule: per flange frame (n, 4, 4) the nominal solution nearest its joint reference
    (n, 6) [deg] (the controller's angles), or the reason there is none: of the closed-form
    solutions (where the arm has them) and, where those may miss one (a near-UR table solved
    through its neighbour) or there are none, Newton's from the reference, the nearest
    within the joint limits."""
    limits = joint_limits_deg(nominal)
    closed = np.full(refs.shape, np.nan)
    try:
        sol = nominal_solutions(nominal, fl, near_deg=refs)
    except ValueError:
        complete = False
    else:
        complete = closed_form_is_complete(nominal)
        idx = choose_nearest(sol, refs)
        closed = np.where((idx >= 0)[:, None], sol.joints_deg[np.arange(len(idx)), idx], np.nan)
    todo = np.flatnonzero(~np.all(np.isfinite(closed), axis=1) | (not complete))
    if todo.size:
        got = solve_flange_ik(nominal, refs[todo], fl[todo], IK_OPTIONS)
        q = got.joints_deg
        ok = got.converged & np.all((q >= limits[:, 0]) & (q <= limits[:, 1]), axis=1)
        d_new = np.where(ok, np.linalg.norm(q - refs[todo], axis=1), np.inf)
        d_old = np.nan_to_num(np.linalg.norm(closed[todo] - refs[todo], axis=1), nan=np.inf)
        better = d_new < d_old - 1e-9
        closed[todo[better]] = q[better]
    found = np.all(np.isfinite(closed), axis=1).tolist()
    why = ["" if f else "no nominal solution within the joint limits" for f in found]
    return list(closed), why


def keeps_nearest(
    nominal: RobotModel,
    rows: list[int],
    ref_of: Mapping[int, FloatArray],
    fk_star: FloatArray,
    q_star: FloatArray,
) -> np.ndarray:
    """Per row (bool): a UR-rule target's corrected pose is still solved, from its joint
    reference, to ``q*`` (the controller would not take another solution); True for the
    other targets."""
    out = np.ones(len(rows), dtype=bool)
    sel = [r for r, i in enumerate(rows) if i in ref_of]
    if not sel:
        return out
    refs = np.array([ref_of[rows[r]] for r in sel])
    qs, why = nearest_solutions(nominal, fk_star[sel], refs)
    found = np.array([not w for w in why], dtype=bool)
    with np.errstate(invalid="ignore"):
        same = np.max(np.abs(np.array(qs) - q_star[sel]), axis=1) < 1e-3
    out[sel] = found & same
    return out
