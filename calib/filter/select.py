"""The branch a controller takes among the nominal IK solutions of a target.

:func:`choose` applies, in order: the only solution within the joint limits; the
configuration's joint ranges (quadrants, signs, turns); the joint reference (UR's nearest
``q``); the branch signs as tie-breakers. See :class:`calib.programs.sites.Configuration`.
"""

from __future__ import annotations

import numpy as np

from calib.filter.branches import Solutions
from calib.kinematics import FloatArray
from calib.programs.sites import OPEN_RANGES_DEG, Configuration


def choose(sol: Solutions, configs: list[Configuration | None]) -> tuple[np.ndarray, list[str]]:
    """The controller's solution per target: index into ``sol``'s candidates (-1 = none)
    and, for -1, the reason.

    Rules, in order: no candidate within the joint limits → unreachable; exactly one → that
    one if the configuration allows it (a controller honouring a configuration stops rather
    than take another: Fanuc, KUKA, ABB with ConfL On), else refused; else the candidates
    within the configuration's joint ranges; of those the one nearest ``nearest_deg`` when
    given; else one left → it; else the branch signs break the tie; still several →
    ambiguous (refused).
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
    return _choose(sol, ranges, near.reshape(n, 6), signs, [c.text for c in cfgs])


def choose_nearest(sol: Solutions, near_deg: FloatArray) -> np.ndarray:
    """:func:`choose` for targets whose configuration is only "nearest these joints"
    ``near_deg`` (n, 6) [deg] (UR's rule), without building a configuration per target: the
    index per target (-1 = none)."""
    n = sol.valid.shape[0]
    ranges = np.broadcast_to(OPEN_RANGES_DEG, (n, 1, 6, 2))
    zero = np.zeros((n, 1), dtype=int)
    idx, _ = _choose(sol, ranges, np.asarray(near_deg, dtype=float), [zero] * 3, None)
    return idx


def _choose(
    sol: Solutions,
    ranges: FloatArray,
    near: FloatArray,
    signs: list[np.ndarray],
    texts: list[str] | None,
) -> tuple[np.ndarray, list[str]]:
    """:func:`choose` on arrays: joint ranges (n, 1, 6, 2) [deg], joint references (n, 6)
    [deg] (NaN rows for none), wanted shoulder, elbow and wrist signs (each (n, 1), 0 for
    any), the configurations' texts for the reasons (None: no reasons wanted)."""
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
