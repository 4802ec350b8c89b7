"""The branch a controller takes among the nominal IK solutions of a target, and the one
definition of leaving it.

:func:`choose` applies, in order: the only solution within the joint limits; the
configuration's joint ranges (quadrants, signs, turns); the joint reference (UR's nearest
``q``); the branch signs as tie-breakers. See :class:`calib.programs.sites.Configuration`.

:func:`left_branch` says when a corrected solution is on another branch than the one it
started from: a joint moved by more than :data:`BRANCH_JUMP_DEG`, or a branch sign
(:func:`branch_of`: shoulder, elbow, wrist) changed. The filter (:mod:`calib.filter.correct`)
and the compensation of CSV targets (:mod:`calib.compensate`) both judge with it.
"""

from __future__ import annotations

import numpy as np

from calib.filter.branches import Solutions, branch_signs
from calib.kinematics import FloatArray
from calib.models import RobotModel
from calib.programs.sites import OPEN_RANGES_DEG, Configuration
from calib.programs.sites import WRIST_SINGULARITY_DEG as WRIST_SINGULARITY_DEG

#: A corrected joint further than this from the solution it started from is another branch
#: [deg] (a joint turning further takes another way round an obstacle or through a
#: singularity): the filter's and compensate's one threshold.
BRANCH_JUMP_DEG = 5.0


def choose(sol: Solutions, configs: list[Configuration | None]) -> tuple[np.ndarray, list[str]]:
    """The controller's solution per target: index into ``sol``'s candidates (-1 = none)
    and, for -1, the reason.

    Rules, in order: no candidate within the joint limits → unreachable; exactly one → that
    one if the configuration allows it (a controller honouring a configuration stops rather
    than take another: Fanuc, KUKA, ABB with ConfL On) or is not honoured, else refused;
    else the candidates within the configuration's joint ranges; of those the one nearest
    ``nearest_deg`` when given; else one left → it; else the branch signs break the tie;
    still several → ambiguous (refused).
    """
    n = sol.valid.shape[0]
    blank = Configuration()
    cfgs = [c or blank for c in configs]
    ranges = np.array([c.joint_ranges_deg for c in cfgs]).reshape(n, 1, 6, 2)
    nan6 = np.full(6, np.nan)
    near = np.array([nan6 if c.nearest_deg is None else c.nearest_deg for c in cfgs])
    signs = [
        np.array([getattr(c, attr) or 0 for c in cfgs])[:, None]
        for attr in ("shoulder", "elbow", "wrist")
    ]
    ignored = np.array([not c.honoured for c in cfgs], dtype=bool)
    return _choose(sol, ranges, near.reshape(n, 6), signs, [c.text for c in cfgs], ignored)


def choose_nearest(sol: Solutions, near_deg: FloatArray) -> np.ndarray:
    """:func:`choose` for targets whose configuration is only "nearest these joints"
    ``near_deg`` (n, 6) [deg] (UR's rule), without building a configuration per target: the
    index per target (-1 = none)."""
    n = sol.valid.shape[0]
    ranges = np.broadcast_to(OPEN_RANGES_DEG, (n, 1, 6, 2))
    zero = np.zeros((n, 1), dtype=int)
    ignored = np.zeros(n, dtype=bool)  # UR: no configuration field, none ignored
    idx, _ = _choose(sol, ranges, np.asarray(near_deg, dtype=float), [zero] * 3, None, ignored)
    return idx


def _choose(
    sol: Solutions,
    ranges: FloatArray,
    near: FloatArray,
    signs: list[np.ndarray],
    texts: list[str] | None,
    ignored: np.ndarray,
) -> tuple[np.ndarray, list[str]]:
    """:func:`choose` on arrays: joint ranges (n, 1, 6, 2) [deg], joint references (n, 6)
    [deg] (NaN rows for none), wanted shoulder, elbow and wrist signs (each (n, 1), 0 for
    any), the configurations' texts for the reasons (None: no reasons wanted), and per
    target (n,) bool whether its configuration is one the controller does not honour (the
    only solution within the limits is then taken whatever the configuration says)."""
    n = sol.valid.shape[0]
    q = sol.joints_deg
    valid = sol.valid
    with np.errstate(invalid="ignore"):
        inr = valid & np.all((q >= ranges[..., 0]) & (q < ranges[..., 1]), axis=2)
    has_near = np.isfinite(near[:, 0])
    m2 = inr.copy()
    for want, have in zip(signs, (sol.shoulder, sol.elbow, sol.wrist), strict=True):
        m2 &= (want == 0) | (have == want)
    n_valid, n_in, n_m2 = valid.sum(axis=1), inr.sum(axis=1), m2.sum(axis=1)
    dist = np.where(
        inr, np.linalg.norm(np.nan_to_num(q - near[:, None, :], nan=np.inf), axis=2), np.inf
    )
    idx = np.full(n, -1)
    several = n_valid > 1
    pick_near = several & (n_in > 0) & has_near
    pick_in = several & (n_in == 1) & ~has_near
    pick_m2 = several & (n_in > 1) & ~has_near & (n_m2 == 1)
    only = (n_valid == 1) & (n_m2 == 1)
    idx[only] = np.argmax(m2[only], axis=1)
    free = (n_valid == 1) & ignored & ~only
    idx[free] = np.argmax(valid[free], axis=1)
    idx[pick_near] = np.argmin(dist[pick_near], axis=1)
    idx[pick_in] = np.argmax(inr[pick_in], axis=1)
    idx[pick_m2] = np.argmax(m2[pick_m2], axis=1)
    reasons = [""] * n
    if texts is None:
        return idx, reasons
    for i in np.flatnonzero(idx < 0):
        text = texts[i] or "(none)"
        if n_valid[i] == 0:
            reasons[i] = "unreachable: no nominal solution within the joint limits"
        elif n_in[i] == 0 or n_m2[i] == 0:
            reasons[i] = f"no nominal solution in configuration {text}"
        else:
            reasons[i] = f"ambiguous: {int(n_m2[i])} nominal solutions fit configuration {text}"
    return idx, reasons


def branch_of(model: RobotModel, joints_deg: FloatArray) -> np.ndarray:
    """``shoulder, elbow, wrist`` signs of the controller's joints (n, 6) [deg]: shape
    (n, 3), int, +1/-1 (:class:`~calib.programs.sites.Configuration`'s definitions). The
    wrist is the sign of joint 5 (+1 when ≥ 0) on every arm; shoulder and elbow are 0
    (unknown) on a model without a closed-form solver."""
    q = np.asarray(joints_deg, dtype=float)
    try:
        return np.stack(branch_signs(model, q), axis=1)
    except ValueError:  # no closed form: the wrist alone
        out = np.zeros((q.shape[0], 3), dtype=int)
        out[:, 2] = np.where(q[:, 4] >= 0, 1, -1)
        return out


def wrist_flipped(a_deg: FloatArray, b_deg: FloatArray, floor_deg: float = 0.0) -> np.ndarray:
    """Per pose (n,): joint 5 changed sign between ``a`` and ``b`` (both (n, 6) [deg]), each
    at least ``floor_deg`` from 0 (the wrist sign of :func:`branch_of`)."""
    a5, b5 = np.asarray(a_deg, dtype=float)[:, 4], np.asarray(b_deg, dtype=float)[:, 4]
    out: np.ndarray = (
        ((a5 >= 0) != (b5 >= 0)) & (np.abs(a5) >= floor_deg) & (np.abs(b5) >= floor_deg)
    )
    return out


def left_branch(
    model: RobotModel,
    from_deg: FloatArray,
    to_deg: FloatArray,
    *,
    jump_deg: float = BRANCH_JUMP_DEG,
    wrist_floor_deg: float = 0.0,
    arm_signs: bool = True,
) -> np.ndarray:
    """Per pose (n,): ``to`` is on another branch than ``from`` (both the controller's joints,
    (n, 6) [deg], on ``model``): a joint moved by more than ``jump_deg``, the wrist flipped
    (:func:`wrist_flipped`, with ``wrist_floor_deg``: 0 for a program whose configuration
    names the wrist, which the controller reads exactly), or, with ``arm_signs``, the
    shoulder or the elbow sign changed (:func:`branch_of`).

    ``arm_signs`` is the filter's rule: a program's Cartesian targets name their configuration,
    and the filter keeps its joint targets on the same branch too. Compensate's CSV rows are
    driven by joint moves, which pass a shoulder or elbow singularity continuously, so there
    a sign that changes with a small correction is no other branch (``arm_signs=False``)."""
    a = np.asarray(from_deg, dtype=float)
    b = np.asarray(to_deg, dtype=float)
    out: np.ndarray = np.max(np.abs(b - a), axis=1) > jump_deg
    out |= wrist_flipped(a, b, wrist_floor_deg)
    if arm_signs:
        out |= np.any(branch_of(model, a)[:, :2] != branch_of(model, b)[:, :2], axis=1)
    return out
