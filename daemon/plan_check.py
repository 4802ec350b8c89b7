"""Did the identification's samples follow the campaign's plan, and what did straying cost?

The plan predicts the tool-point σ its poses give (``summary.tcp_sigma_mm.plan``); the
identification reports the σ its samples gave (``tcp_uncertainty_mm``, both from
:mod:`calib.tcp`). When the samples are not the plan's poses (the robot ran poses of its own,
or the capture stopped early) the two part, and the result says so: ``plan_check`` in the
result and a note among its ``notes``. A pose counts as measured by the same rule as the
plan's progress (:func:`daemon.store.match_poses`, tolerance :data:`daemon.store.MATCH_TOL_DEG`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from calib.dataset import JOINT_COLUMNS
from daemon.store import MATCH_TOL_DEG, StoreNotFound, match_poses

#: Achieved over planned TCP σ RMS above which a result on the plan is still worth a word.
SIGMA_RATIO_NOTE = 1.5


def plan_check(
    store: Any, campaign_id: int, sample_ids: list[int], result: dict[str, Any]
) -> dict[str, Any] | None:
    """The plan check of a result identified from ``sample_ids`` of the campaign, or None
    when the campaign has no plan.

    Returns
    -------
    dict
        ``plan_id``, ``n_planned``, ``n_measured`` (planned poses a sample measured),
        ``n_samples``, ``n_off_plan`` (samples at no planned pose), ``on_plan`` (every planned
        pose measured), ``tol_deg``, ``planned_tcp_sigma_mm`` and ``achieved_tcp_sigma_mm``
        (``{"rms", "max"}`` [mm]), ``sigma_ratio`` (achieved / planned RMS), ``plan_noise_mm``
        (the noise the plan assumed) and ``plan_noise_source`` (where it came from, see
        :mod:`daemon.plan_noise`; None for plans made before), ``fit_noise_mm`` (the noise
        the fit ran with), ``planned_rms_at_fit_noise_mm`` (the plan's RMS scaled to that
        noise: σ is linear in the noise) and ``sigma_ratio_at_fit_noise`` (achieved over it),
        ``note``.
    """
    try:
        plan = store.latest_plan(campaign_id)
    except StoreNotFound:
        return None
    samples, ids = store.sample_set(campaign_id)
    wanted = set(sample_ids)
    keep = [i for i, sid in enumerate(ids) if sid in wanted]
    joints = samples.joints_deg[keep] if keep else np.empty((0, 6))
    anchors = [str(samples.anchor[i]) for i in keep]
    poses = plan["poses"]
    planned = np.array([[float(p[c]) for c in JOINT_COLUMNS] for p in poses], dtype=np.float64)
    match = match_poses(planned, [str(p["anchor"]) for p in poses], joints, anchors)
    n_planned, n_measured = len(poses), int(np.count_nonzero(match >= 0))
    n_off = len(keep) - len({int(k) for k in match if k >= 0})
    summary = plan.get("summary") or {}
    planned_tcp = ((summary.get("tcp_sigma_mm") or {}).get("plan")) or {}
    achieved = result.get("tcp_uncertainty_mm") or {}
    p_rms, a_rms = planned_tcp.get("rms"), achieved.get("rms")
    ratio = float(a_rms) / float(p_rms) if p_rms and a_rms is not None else None
    on_plan = n_measured == n_planned
    # The plan assumed a length noise; the fit estimates its own (captures are window means,
    # so usually quieter). The plan's σ at the fit's noise separates design from noise.
    plan_noise = summary.get("noise_mm")
    fit_noise = (result.get("prior") or {}).get("noise_mm")
    same_noise = (
        float(p_rms) * float(fit_noise) / float(plan_noise)
        if p_rms and plan_noise and fit_noise
        else None
    )
    sigma = (
        f"tool-point σ RMS {a_rms:.3f} mm against {p_rms:.3f} mm planned (x{ratio:.2f})"
        if ratio is not None
        else "no tool-point σ to compare"
    )
    if on_plan:
        note = f"The samples measured all {n_planned} planned poses: {sigma}."
        if n_off:
            note += f" {n_off} further samples are off the plan."
        if ratio is not None and ratio > SIGMA_RATIO_NOTE:
            note += (
                f" The plan assumed {summary.get('noise_mm')} mm length noise (from "
                f"{summary.get('noise_source') or 'the request'}); a higher σ means noisier "
                "lengths than that (check the cable and the settle window)."
            )
    else:
        note = (
            f"The samples stray from the plan {plan['id']}: {n_measured} of {n_planned} planned "
            f"poses measured, {n_off} samples off the plan; {sigma}. Run the plan's program "
            "on the robot (the plan's download, or cablecal program) and capture the pending "
            "poses, or plan again on top of these samples."
        )
    return {
        "plan_id": int(plan["id"]),
        "n_planned": n_planned,
        "n_measured": n_measured,
        "n_samples": len(keep),
        "n_off_plan": n_off,
        "on_plan": on_plan,
        "tol_deg": MATCH_TOL_DEG,
        "planned_tcp_sigma_mm": planned_tcp,
        "achieved_tcp_sigma_mm": achieved,
        "sigma_ratio": ratio,
        "plan_noise_mm": plan_noise,
        "plan_noise_source": summary.get("noise_source"),
        "fit_noise_mm": fit_noise,
        "planned_rms_at_fit_noise_mm": same_noise,
        "sigma_ratio_at_fit_noise": (
            float(a_rms) / same_noise if same_noise and a_rms is not None else None
        ),
        "note": note,
    }


def add_plan_check(
    store: Any, campaign_id: int, sample_ids: list[int], result: dict[str, Any]
) -> None:
    """Put :func:`plan_check` into ``result`` (``plan_check``, and its note in ``notes`` when
    the samples stray from the plan or fall short of its prediction)."""
    check = plan_check(store, campaign_id, sample_ids, result)
    if check is None:
        return
    result["plan_check"] = check
    ratio = check["sigma_ratio"]
    if not check["on_plan"] or (ratio is not None and ratio > SIGMA_RATIO_NOTE):
        result.setdefault("notes", []).append(check["note"])
