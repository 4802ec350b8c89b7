"""Which planned poses the samples measured: a plan's progress, and what straying cost.

:func:`match_poses` marks a planned pose done from the samples; :func:`match_plan` applies it
to a stored plan's pose rows; :func:`plan_check` compares an identification's samples and
result with the plan (the daemon reads both from its store: :mod:`daemon.jobs.plan_check`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from calib.dataset import JOINT_COLUMNS
from calib.kinematics import FloatArray, IndexArray
from calib.result import CalibrationResult, ResultLike

#: Default tolerance per joint for a sample to count as a planned pose [deg]: a robot reaches
#: a commanded pose to a few hundredths of a degree; 0.5 deg also accepts a pose taught by
#: hand near the plan.
MATCH_TOL_DEG = 0.5
#: Achieved over planned TCP σ RMS above which a result on the plan is still worth a word.
SIGMA_RATIO_NOTE = 1.5
#: Refusal reasons (the sampler's, :data:`daemon.sampler.capture.REJECTION_STATUS`) that say a
# planned
#: pose cannot be captured as planned: the indicator over or under its range there, or a pose
#: that never settled within the capture timeout. A device error or a stale reading may pass
#: on a retry, so they do not.
NOT_CAPTURABLE_REASONS = ("over_range", "moving")


def match_poses(
    planned_deg: FloatArray | Sequence[Sequence[float]],
    planned_anchor: Sequence[str],
    sample_deg: FloatArray | Sequence[Sequence[float]],
    sample_anchor: Sequence[str],
    tol_deg: float = MATCH_TOL_DEG,
) -> IndexArray:
    """For each planned pose, the sample that measured it, or -1.

    A sample measures a planned pose when it was taken at the same anchor and every joint is
    within ``tol_deg`` of the plan (:data:`MATCH_TOL_DEG`). Among several, the closest
    (smallest largest-joint difference) wins.

    Progress is computed from the samples rather than stored when a capture happens: auto and
    manual captures and CSV imports all end as samples, so every way of measuring a pose
    counts, a sample excluded later (callers pass the included ones) makes its pose pending
    again, and a restart loses nothing. The cost is one (n × m × 6) comparison per request
    (500 planned poses × 2000 samples: 6 million differences, milliseconds).

    Parameters
    ----------
    planned_deg : ndarray, shape (n, 6) [deg]
    planned_anchor : sequence of str, length n
    sample_deg : ndarray, shape (m, 6) [deg]
    sample_anchor : sequence of str, length m
    tol_deg : float
        Largest allowed difference per joint [deg]; > 0.

    Returns
    -------
    ndarray of int, shape (n,)
        Index into the samples, or -1 (pending).

    Raises
    ------
    ValueError
        ``tol_deg`` not > 0 (naming it).
    """
    if not tol_deg > 0:
        raise ValueError(f"tol_deg: must be > 0, got {tol_deg}")
    planned = np.asarray(planned_deg, dtype=float).reshape(-1, 6)
    sampled = np.asarray(sample_deg, dtype=float).reshape(-1, 6)
    n = planned.shape[0]
    out = np.full(n, -1, dtype=int)
    if n == 0 or sampled.shape[0] == 0:
        return out
    diff = np.abs(planned[:, None, :] - sampled[None, :, :]).max(axis=2)  # (n, m)
    same = np.asarray(planned_anchor)[:, None] == np.asarray(sample_anchor)[None, :]
    diff = np.where(same, diff, np.inf)
    best = np.argmin(diff, axis=1)
    ok = diff[np.arange(n), best] <= tol_deg
    out[ok] = best[ok]
    return out


def match_plan(
    poses: Sequence[Mapping[str, Any]],
    sample_deg: FloatArray | Sequence[Sequence[float]],
    sample_anchor: Sequence[str],
    tol_deg: float = MATCH_TOL_DEG,
) -> list[int]:
    """:func:`match_poses` of a plan's pose rows (each with ``q1..q6`` [deg] and ``anchor``):
    per pose, the index of the sample that measured it, or -1."""
    planned = [[float(p[c]) for c in JOINT_COLUMNS] for p in poses]
    anchors = [str(p["anchor"]) for p in poses]
    return [int(k) for k in match_poses(planned, anchors, sample_deg, sample_anchor, tol_deg)]


def not_capturable(
    poses: Sequence[Mapping[str, Any]],
    match: Sequence[int],
    rejections: Sequence[Mapping[str, Any]],
    tol_deg: float = MATCH_TOL_DEG,
) -> list[str | None]:
    """Per planned pose not measured (``match`` -1, :func:`match_plan`): why it cannot be
    captured, or None. ``rejections`` are refused captures, oldest first, each with
    ``reason``, ``detail`` and ``joints_deg`` (6 [deg], the pose it was refused at; ones
    without it are skipped); a refusal of a reason in :data:`NOT_CAPTURABLE_REASONS` with
    every joint within ``tol_deg`` of the pose marks it, with the newest such refusal's
    ``"reason: detail"``. A measured pose is never marked."""
    known = [
        r
        for r in rejections
        if r.get("reason") in NOT_CAPTURABLE_REASONS
        and isinstance(r.get("joints_deg"), list | tuple)
        and len(r["joints_deg"]) == 6
    ]
    out: list[str | None] = [None] * len(poses)
    if not known:
        return out
    at = np.array([[float(v) for v in r["joints_deg"]] for r in known])  # (m, 6) [deg]
    for i, (pose, k) in enumerate(zip(poses, match, strict=True)):
        if k >= 0:
            continue
        q = np.array([float(pose[c]) for c in JOINT_COLUMNS])
        near = np.flatnonzero(np.abs(at - q).max(axis=1) <= tol_deg)
        if near.size:
            r = known[int(near[-1])]
            out[i] = f"{r['reason']}: {r.get('detail', '')}"
    return out


def plan_check(
    plan: Mapping[str, Any],
    joints_deg: FloatArray | Sequence[Sequence[float]],
    anchors: Sequence[str],
    result: ResultLike,
    rejections: Sequence[Mapping[str, Any]] = (),
) -> dict[str, Any]:
    """The plan check of a result identified from samples at ``joints_deg`` (n, 6) [deg] with
    their ``anchors``, against the stored ``plan`` (``id``, ``poses``, ``summary``).

    Returns
    -------
    dict
        ``plan_id``, ``n_planned``, ``n_measured`` (planned poses a sample measured),
        ``n_samples``, ``n_off_plan`` (samples at no planned pose), ``on_plan`` (every planned
        capturable pose measured), ``n_not_capturable`` (pending poses the sampler refused
        for good, :func:`not_capturable` of ``rejections``: counted apart, never asked
        for), ``tol_deg``, ``planned_tcp_sigma_mm`` and ``achieved_tcp_sigma_mm``
        (``{"rms", "max"}`` [mm]), ``sigma_ratio`` (achieved / planned RMS), ``plan_noise_mm``
        (the noise the plan assumed) and ``plan_noise_source`` (where it came from, see
        :mod:`daemon.api.plan_noise`; None for plans made before), ``fit_noise_mm`` (the noise
        the fit ran with), ``planned_rms_at_fit_noise_mm`` (the plan's RMS scaled to that
        noise: σ is linear in the noise) and ``sigma_ratio_at_fit_noise`` (achieved over it),
        ``note``.
    """
    res = CalibrationResult.of(result)
    poses = plan["poses"]
    match = match_plan(poses, joints_deg, anchors)
    n_samples = len(anchors)
    n_planned, n_measured = len(poses), sum(1 for k in match if k >= 0)
    why = not_capturable(poses, match, rejections)
    impossible = [
        int(p["pose"]) if "pose" in p else i + 1
        for i, (p, w) in enumerate(zip(poses, why, strict=True))
        if w
    ]
    n_not = len(impossible)
    n_off = n_samples - len({k for k in match if k >= 0})
    summary = plan.get("summary") or {}
    planned_tcp = ((summary.get("tcp_sigma_mm") or {}).get("plan")) or {}
    achieved = dict(res.tcp_uncertainty_mm or {})
    p_rms, a_rms = planned_tcp.get("rms"), achieved.get("rms")
    ratio = float(a_rms) / float(p_rms) if p_rms and a_rms is not None else None
    on_plan = n_measured + n_not == n_planned
    aside = (
        f" {n_not} planned pose(s) cannot be captured (pose {', '.join(map(str, impossible))}: "
        "the sampler refused them, e.g. over the indicator's range); plan again to replace "
        "them."
        if n_not
        else ""
    )
    # The plan assumed a length noise; the fit estimates its own (captures are window means,
    # so usually quieter). The plan's σ at the fit's noise separates design from noise.
    plan_noise = summary.get("noise_mm")
    fit_noise = res.prior.noise_mm if res.prior else None
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
        note = f"The samples measured all {n_measured} capturable planned poses: {sigma}."
        note += aside
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
        ) + aside
    return {
        "plan_id": int(plan["id"]),
        "n_planned": n_planned,
        "n_measured": n_measured,
        "n_samples": n_samples,
        "n_off_plan": n_off,
        "n_not_capturable": n_not,
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


def worth_a_note(check: Mapping[str, Any]) -> bool:
    """Whether a :func:`plan_check` goes into the result's notes: the samples stray from the
    plan, some planned poses cannot be captured, or they fall short of its prediction by more
    than :data:`SIGMA_RATIO_NOTE`."""
    ratio = check["sigma_ratio"]
    return (
        not check["on_plan"]
        or bool(check.get("n_not_capturable"))
        or (ratio is not None and ratio > SIGMA_RATIO_NOTE)
    )
