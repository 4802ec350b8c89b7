"""Steps 3 and 4 of an identification: where every method starts (the nominal DH table with
the tool point, ``P0`` and ``c`` fitted) and what it solves for (the base set at that start,
plus parameters freed by name, minus parameters fixed by name).
"""

from __future__ import annotations

import numpy as np

from calib import methods
from calib.anchors import plain_fit
from calib.cable import N_DH, N_KIN, length_jacobian
from calib.identifiability import (
    Identifiability,
    analyse,
    candidate_mask,
    generic_jacobian,
    solved_mask,
)
from calib.identify.prepared import Prepared
from calib.kinematics import FloatArray
from calib.options import IdentifyOptions, check_training_rows
from calib.problem import Problem


def start_point(
    d: Prepared, theta_before: FloatArray, opts: IdentifyOptions
) -> tuple[FloatArray, np.ndarray]:
    """Step 3: the common start (nominal DH, tool and anchors fitted) and the candidate mask."""
    layout = d.layout
    candidates = candidate_mask(layout, opts.identify_tool, opts.fix)
    theta_start = theta_before
    if candidates[N_DH:N_KIN].any():
        free0 = np.zeros(layout.size, dtype=bool)
        free0[N_DH:] = candidates[N_DH:]
        prob = Problem(d.model, layout, d.q, d.length_mm, d.aidx, free0, theta_before)
        theta_start = plain_fit(prob)
    return theta_start, candidates


def free_set(
    d: Prepared, theta_start: FloatArray, candidates: np.ndarray, opts: IdentifyOptions
) -> tuple[Identifiability, np.ndarray]:
    """Step 4: identifiability at the start, and the solved set (base set, ± names)."""
    layout = d.layout
    _, jac = length_jacobian(d.model, theta_start, d.q, d.aidx)
    generic = generic_jacobian(d.model, layout, theta_start)
    plausible = methods.internal_sigma(layout, opts.prior_mm, opts.prior_deg, np.inf)
    ident = analyse(
        jac,
        layout.names,
        candidates,
        rtol=opts.rtol,
        structural_jacobian=generic,
        noise_mm=opts.noise_mm if opts.noise_rank else None,
        plausible=plausible,
    )
    free = solved_mask(layout, ident.base, candidates, opts.free)
    # validate() checked the bound before any fit; this checks the count on these data.
    check_training_rows(d.train_rows.size, len(d.samples), int(np.count_nonzero(free)))
    return ident, free
