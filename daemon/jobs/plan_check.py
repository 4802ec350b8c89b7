"""Did the identification's samples follow the campaign's plan, and what did straying cost?

The plan predicts the tool-point σ its poses give (``summary.tcp_sigma_mm.plan``); the
identification reports the σ its samples gave (``tcp_uncertainty_mm``, both from
:mod:`calib.tcp`). When the samples are not the plan's poses (the robot ran poses of its own,
or the capture stopped early) the two part, and the result says so: ``plan_check`` in the
result and a note among its ``notes``. A pose counts as measured by the same rule as the
plan's progress (:func:`calib.planning.progress.match_poses`, tolerance
:data:`calib.planning.progress.MATCH_TOL_DEG`). The comparison is calib's
(:func:`calib.planning.progress.plan_check`); this module reads the plan and the samples.
"""

from __future__ import annotations

from typing import Any

from daemon.store import StoreNotFound


def plan_check(
    store: Any, campaign_id: int, sample_ids: list[int], result: dict[str, Any]
) -> dict[str, Any] | None:
    """The plan check (:func:`calib.planning.progress.plan_check`) of a result identified
    from ``sample_ids`` of the campaign, or None when the campaign has no plan."""
    from calib.planning.progress import plan_check as check_against_plan

    try:
        plan = store.latest_plan(campaign_id)
    except StoreNotFound:
        return None
    samples, ids = store.sample_set(campaign_id)
    wanted = set(sample_ids)
    keep = [i for i, sid in enumerate(ids) if sid in wanted]
    joints = [samples.joints_deg[i] for i in keep]
    anchors = [str(samples.anchor[i]) for i in keep]
    return check_against_plan(plan, joints, anchors, result, rejections(store, campaign_id))


#: Most refused captures of a campaign read for its plan (the newest).
MAX_REJECTIONS = 5000


def rejections(store: Any, campaign_id: int) -> list[dict[str, Any]]:
    """The campaign's refused captures (``capture_rejected`` events' details: ``reason``,
    ``detail``, ``joints_deg`` when the pose was known), oldest first, at most the newest
    :data:`MAX_REJECTIONS`: what :func:`calib.planning.progress.not_capturable` reads."""
    events = store.list_events(
        kind="capture_rejected", campaign_id=campaign_id, limit=MAX_REJECTIONS
    )
    return [dict(e["detail"]) for e in events if isinstance(e.get("detail"), dict)]


def add_plan_check(
    store: Any, campaign_id: int, sample_ids: list[int], result: dict[str, Any]
) -> dict[str, Any]:
    """``result`` with :func:`plan_check` in it (``plan_check``, and its note in ``notes`` when
    the samples stray from the plan or fall short of its prediction:
    :func:`calib.planning.progress.worth_a_note`); ``result`` itself when the campaign has no
    plan."""
    from calib.planning.progress import worth_a_note
    from calib.result import CalibrationResult

    check = plan_check(store, campaign_id, sample_ids, result)
    if check is None:
        return result
    note = str(check["note"]) if worth_a_note(check) else None
    return CalibrationResult.from_json(result).with_plan_check(check, note)
