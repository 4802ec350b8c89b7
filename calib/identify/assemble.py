"""Step 6 of an identification: the result assembled from the fit: the drift block, the
covariance and every parameter's σ (:mod:`calib.identify.covariance`), the tool-point σ
after best rigid alignment (:mod:`calib.tcp`), the plausibility of every parameter
(:mod:`calib.identify.plausibility`), the length figures before and after on the training
and the test rows, and the notes.

Units: internal values in millimetres and radians; every reported figure in degrees and
millimetres.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from calib import drift
from calib.cable import N_KIN
from calib.identifiability import Identifiability
from calib.identify.covariance import covariance, uncertainty
from calib.identify.plausibility import implausibility_advice, plausibility
from calib.identify.prepared import Prepared
from calib.identify.result_json import (
    IdentifyResult,
    drift_report,
    drift_summary,
    length_figures,
    robust_detail,
    robust_note,
)
from calib.kinematics import FloatArray
from calib.options import IdentifyOptions, PriorOptions, part
from calib.prior import prior_block
from calib.robust import Solved
from calib.tcp import tcp_uncertainty_for_problem
from calib.timing import Timer


def drift_mm(d: Prepared, theta: FloatArray, beta: FloatArray, rows: np.ndarray) -> FloatArray:
    """The drift terms (r,) [mm] at ``rows`` (interpolated at their times) under ``theta``."""
    if d.drift_model is None or rows.size == 0:
        return np.zeros(rows.size)
    basis = d.drift_model.basis(d.times[0][rows], d.units(theta, rows))
    return np.asarray(basis @ beta, dtype=float)


def figures(
    d: Prepared, theta_before: FloatArray, theta: FloatArray, beta: FloatArray
) -> dict[str, dict[str, dict[str, float]]]:
    """Length metrics before and after, on the training and the test rows; the after figures
    with the drift terms ``beta`` (m,) [mm] at each row's time (none before)."""
    return length_figures(
        d.samples.length_mm,
        {"train": d.train_rows, "test": d.test_rows},
        {
            "before": lambda rows: d.lengths(theta_before, rows),
            "after": lambda rows: d.lengths(theta, rows) + drift_mm(d, theta, beta, rows),
        },
    )


def assemble(
    d: Prepared,
    opts: IdentifyOptions,
    *,
    theta_before: FloatArray,
    theta_start: FloatArray,
    ident: Identifiability,
    free: np.ndarray,
    selection: drift.Selection | None,
    weighed: tuple[PriorOptions, dict[str, Any], Solved],
    timer: Timer,
) -> IdentifyResult:
    """Step 6: the result of the fit ``weighed`` (the prior used, its detail, the robust fit,
    as :func:`calib.identify.fit.weighed_solve` returns them) from the start ``theta_start``
    (p,) on the solved set ``free`` (p,); ``theta_before`` (p,) is the nominal model with its
    anchors fitted, ``selection`` the drift choice (None: not looked for). ``elapsed_s`` is
    ``timer``'s when the result is made."""
    used, prior_detail, solved = weighed
    layout = d.layout
    notes: list[str] = []
    if used.prior:
        notes.append(
            f"MAP prior toward the nominal model: {used.prior_mm} mm / {used.prior_deg} deg "
            f"per DH error, noise {used.noise_mm:.3g} mm"
        )
    result, final = solved.result, solved.problem
    if opts.robust != "none":
        notes.append(robust_note(opts, solved, d.train_rows.size, len(d.samples)))

    x = result.x
    theta = final.full(x)
    beta = final.drift_coefficients(x)
    drift_block = None
    if opts.drift != "none":
        drift_block = drift_report(
            d.drift_model or drift.DriftModel(time_unit=d.times[1]), beta, selection, opts.drift
        )
        every = np.arange(len(d.samples))
        drift_block["per_sample_mm"] = drift_mm(d, theta, beta, every).tolist()
        drift_block["rows_flagged"] = [int(d.train_rows[i]) for i in solved.flagged]
        if opts.method not in drift.DRIFT_METHODS:
            drift_block["note"] = f"not modelled: method {opts.method} does not support it"
        # The one wording of what was found: the CLI, the HTML report and the page read it.
        drift_block["summary"] = drift_summary(drift_block)
    cov, _ = covariance(final, x)
    sigma, corr = uncertainty(final, x, cov)
    # The covariance propagated to the tool point over a workspace sample within the joint
    # limits, after removing the rigid motions distances cannot see (calib.tcp).
    tcp = tcp_uncertainty_for_problem(final, x, cov).to_dict()
    extension = (
        d.lengths(theta, np.arange(len(d.samples))) - theta[N_KIN:].reshape(-1, 4)[d.aidx_all, 3]
    )
    plaus = plausibility(layout, theta, d.model.tool_mm, extension)
    if not plaus["plausible"]:
        notes.append(implausibility_advice(layout, final.free_names, sigma, cov, plaus, opts))
    flagged = [int(d.train_rows[i]) for i in solved.flagged]
    return IdentifyResult(
        model=d.model,
        layout=layout,
        method=opts.method,
        theta=theta,
        theta_before=theta_before,
        free_names=[n for n, f in zip(layout.names, free, strict=True) if f],
        sigma=sigma,
        correlation=corr,
        identifiability=ident,
        solver=result,
        metrics=figures(d, theta_before, theta, beta),
        flagged_rows=flagged,
        train_rows=d.train_rows,
        test_rows=d.test_rows,
        options=opts,
        plausibility=plaus,
        notes=notes,
        elapsed_s=timer.elapsed(),
        theta_start=theta_start,
        tcp_uncertainty_mm=tcp,
        prior=prior_block(part(opts, PriorOptions), used, prior_detail),
        robust_detail=robust_detail(opts, solved),
        drift=drift_block,
    )
