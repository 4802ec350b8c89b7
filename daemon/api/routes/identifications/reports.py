"""A job's result as the HTML calibration report, and its residuals per sample (the operator
page's before/after plots). Both use the campaign's included samples as they are now."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, HTTPException
from fastapi.responses import HTMLResponse
from typing_extensions import TypedDict

from calib.result import CalibrationResult
from daemon.api.deps import JobId, ReadAuth, State
from daemon.api.errors import error_responses
from daemon.api.http.downloads import download_headers

router = APIRouter(tags=["identifications"], responses=error_responses(401, 404, 409, 413, 422))


class Residuals(TypedDict):
    """Residuals per included sample, measured minus model [mm] (lists of length n, in
    sample id order). ``before_mm`` is null when the nominal tool point is unknown;
    ``before_note`` says how the before model was obtained; ``n_job_samples`` is how many
    samples the job used (train + test), which differs from n when samples were captured,
    excluded or included since."""

    sample_ids: list[int]
    after_mm: list[float]
    before_mm: list[float] | None
    before_note: str
    n_job_samples: int | None


def _result_and_residuals(state: State, job_id: int) -> tuple[dict[str, Any], Any, list[int]]:
    """The job's result, its :class:`calib.html_report.SampleResiduals` on the campaign's
    included samples, and their sample ids. 409 while the job has no result."""
    from calib.html_report import sample_residuals

    job = state.store.job(job_id)
    row = state.store.get_result_for_job(job_id)
    if row is None:
        raise HTTPException(409, f"identification {job_id}: has no result (status {job['status']})")
    result = row["result"]
    samples, ids = state.store.sample_set(int(job["campaign_id"]))
    if len(ids) == 0:
        raise HTTPException(409, f"campaign {job['campaign_id']}: has no included samples")
    try:
        residuals = sample_residuals(result, samples, state.store.robot_model(int(job["robot_id"])))
    except ValueError as exc:
        raise HTTPException(409, f"identification {job_id}: {exc}") from exc
    return result, residuals, ids


@router.get(
    "/identifications/{job_id}/residuals",
    summary="Residuals per sample, before and after",
    dependencies=[ReadAuth],
)
def residuals(state: State, job_id: JobId) -> Residuals:
    """Before (nominal model, P0 and offset fitted) and after (calibrated model) residuals of
    every included sample of the job's campaign [mm]."""
    result, res, ids = _result_and_residuals(state, job_id)
    split = CalibrationResult.from_json(result).split
    n_train, n_test = (split.n_train, split.n_test) if split else (None, None)
    return {
        "sample_ids": ids,
        "after_mm": [float(v) for v in res.after_mm],
        "before_mm": None if res.before_mm is None else [float(v) for v in res.before_mm],
        "before_note": res.before_note,
        "n_job_samples": n_train + n_test
        if isinstance(n_train, int) and isinstance(n_test, int)
        else None,
    }


@router.get(
    "/identifications/{job_id}/report.html",
    summary="The calibration report (HTML)",
    dependencies=[ReadAuth],
    responses={200: {"content": {"text/html": {}}, "description": "The report"}},
)
def report_html(state: State, job_id: JobId) -> HTMLResponse:
    """One self-contained HTML document (inline CSS and SVG, no script): the result with its
    residuals per sample; opens offline and prints on A4 (``cablecal report`` writes the
    same page from a result.json file)."""
    from calib.html_report import render_report_html

    result, res, _ = _result_and_residuals(state, job_id)
    html = render_report_html(result, res, source=f"identification {job_id}")
    return HTMLResponse(
        html,
        headers=download_headers(f"identification-{job_id}-report.html", "inline"),
    )
