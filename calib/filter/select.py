"""The branch a controller takes among the nominal IK solutions of a target.

:func:`choose` applies, in order: the only solution within the joint limits; the
configuration's joint ranges (quadrants, signs, turns); the joint reference (UR's nearest
``q``); the branch signs as tie-breakers. See :class:`calib.filter.sites.Configuration`.
"""

from __future__ import annotations

import numpy as np

from calib.filter.branches import Solutions
from calib.filter.sites import Configuration


def choose(sol: Solutions, configs: list[Configuration | None]) -> tuple[np.ndarray, list[str]]:
    """The controller's solution per target: index into ``sol``'s candidates (-1 = none)
    and, for -1, the reason.

    Rules, in order: no candidate within the joint limits → unreachable; exactly one → that
    one; else the candidates within the configuration's joint ranges; of those the one
    nearest ``nearest_deg`` when given; else one left → it; else the branch signs break the
    tie; still several → ambiguous (refused).
    """
    n = sol.valid.shape[0]
    idx = np.full(n, -1)
    reasons = [""] * n
    q = sol.joints_deg
    n_valid = sol.valid.sum(axis=1)
    one = n_valid == 1
    idx[one] = np.argmax(sol.valid[one], axis=1)
    for i in np.flatnonzero(n_valid == 0):
        reasons[i] = "unreachable: no nominal solution within the joint limits"
    for i in np.flatnonzero(n_valid > 1):
        cfg = configs[i] or Configuration()
        ranges = cfg.joint_ranges_deg
        with np.errstate(invalid="ignore"):
            m = sol.valid[i] & np.all((q[i] >= ranges[:, 0]) & (q[i] < ranges[:, 1]), axis=1)
        if not m.any():
            reasons[i] = f"no nominal solution in configuration {cfg.text or '(none)'}"
            continue
        if cfg.nearest_deg is not None:
            d = np.where(m, np.linalg.norm(np.nan_to_num(q[i] - cfg.nearest_deg), axis=1), np.inf)
            idx[i] = int(np.argmin(d))
            continue
        if m.sum() == 1:
            idx[i] = int(np.argmax(m))
            continue
        m2 = m.copy()
        for want, have in ((cfg.shoulder, sol.shoulder[i]), (cfg.elbow, sol.elbow[i]),
                           (cfg.wrist, sol.wrist[i])):  # fmt: skip
            if want is not None:
                m2 &= have == want
        if m2.sum() == 1:
            idx[i] = int(np.argmax(m2))
        elif m2.sum() == 0:
            reasons[i] = f"no nominal solution in configuration {cfg.text or '(none)'}"
        else:
            reasons[i] = (f"ambiguous: {int(m2.sum())} nominal solutions fit configuration "
                          f"{cfg.text or '(none)'}")  # fmt: skip
    return idx, reasons
