"""Identification of a robot's DH errors, tool point, anchors and zero offsets from cable lengths.

The public entry point is :func:`identify` (:mod:`calib.identify.run` runs the steps in
order). It

1. checks the options against the samples (:func:`calib.options.validate`) and splits them
   into training and test rows (random, grouped, or given; :func:`calib.split.check`), and
   holds them as arrays, the tool override applied (:mod:`calib.identify.prepared`);
2. fits the *before* model: nominal kinematics with only ``P0`` and ``c`` per anchor, started
   by linear multilateration (:func:`calib.cable.multilaterate`) and refined by LM
   (:func:`calib.anchors.fit_anchors`);
3. starts the full identification from the nominal DH table with the tool point, ``P0`` and
   ``c`` fitted (so that every method starts from the same, data-driven point, and no manual
   guess is needed; :func:`calib.identify.start_point.start_point`);
4. analyses identifiability at that point (:mod:`calib.identifiability`) and solves for the
   base parameter set, plus parameters freed by name, minus parameters fixed by name
   (:func:`calib.identify.start_point.free_set`);
   then (``drift``, :func:`calib.identify.fit.select_drift`) tests the plain fit for steps
   and a smooth drift of the measurement over the campaign (:mod:`calib.drift`); a chosen
   model's terms are profiled out of the problem (:class:`calib.problem.Problem`'s drift
   basis) for every later fit, and the test rows' figures add them at each row's time;
5. weighs the optional Gaussian prior toward the nominal model (MAP) by the noise its own MAP
   fits estimate, or by grouped-fold cross-validation (:func:`calib.prior.weighed_solve`), and runs
   the chosen method (:data:`calib.methods.REGISTRY`), robustly by default: ``auto`` fits, tests
   the leverage-studentised residuals (prior included) against a MAD scale and a threshold
   growing with ``n`` and with the scale's uncertainty, when the redundancy allows screening,
   and only on outliers (or gross errors) rejects them and refits from the start; IRLS with Huber or
   soft-L1 weights, or rejection at 3.5σ, on request (:func:`calib.robust.solve`;
   :func:`calib.identify.fit.weighed_solve`);
6. assembles the result (:mod:`calib.identify.assemble`): the covariance
   ``(JᵀJ/σ̂² + Σ_prior⁻¹)⁻¹`` with ``σ̂² = Σ w r² / (n − k)``
   (:mod:`calib.identify.covariance`), the metrics before and after on train and test, the
   plausibility of every parameter (:mod:`calib.identify.plausibility`) and the predicted
   tool-point σ after best rigid alignment (:mod:`calib.tcp`), as an :class:`IdentifyResult`
   whose :meth:`~IdentifyResult.to_json` is ``result.json`` (:mod:`calib.identify.result_json`).

Units: inputs in degrees and millimetres; internal computation in radians and millimetres;
every reported figure in degrees and millimetres.

The split, the robust weights, the prior's weight and the drift model keep their own
modules beside this package (:mod:`calib.split`, :mod:`calib.robust`, :mod:`calib.prior`,
:mod:`calib.drift`): the daemon's job check and other callers use them without the solvers,
and a module of this package loads the whole package (its ``__init__`` imports the run).
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
