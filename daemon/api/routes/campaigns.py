"""Campaigns, captures and samples."""

from __future__ import annotations

import logging
from collections.abc import AsyncIterator, Iterator
from typing import cast

from fastapi import APIRouter, HTTPException, Query, Request, Response, status
from fastapi.responses import StreamingResponse
from starlette.concurrency import run_in_threadpool

from calib.dataset import (
    JOINT_COLUMNS,
    SampleError,
    SampleSet,
    known_pose_index,
    make_samples,
    parse_samples_csv,
    validate_joint_limits,
)
from daemon.api.deps import (
    AppState,
    CampaignId,
    Paged,
    PagedLarge,
    ReadAuth,
    SampleId,
    State,
    WriteAuth,
    link_next,
    require_space,
)
from daemon.api.downloads import download_headers
from daemon.api.errors import Error, error_responses, unprocessable
from daemon.api.guard import MAX_IMPORT_BYTES
from daemon.api.offload import offload
from daemon.api.routes.robots import robot_for_campaign
from daemon.api.schemas import (
    AutoCapture,
    CampaignCreate,
    CampaignOut,
    CaptureRequest,
    ImportResult,
    SampleOut,
    SamplePatch,
)
from daemon.api.text_rules import not_printable
from daemon.autocapture import SamplerRefused, SamplerUnavailable
from daemon.capture import CaptureRejected
from daemon.store import CampaignRow

log = logging.getLogger("cablecal.service")

#: Content-Types a CSV import accepts (anything else, e.g. application/json, is a 415).
IMPORT_MEDIA_TYPES = frozenset({"text/csv"})

router = APIRouter(tags=["campaigns"], responses=error_responses(400, 401, 413, 422))


@router.post(
    "/campaigns",
    status_code=status.HTTP_201_CREATED,
    summary="Create a campaign",
    dependencies=[WriteAuth],
    responses=error_responses(429, 507),
)
def create_campaign(state: State, request: Request, body: CampaignCreate) -> CampaignOut:
    """The robot: ``robot_id`` (an existing one), or ``robot`` (its own name; default: the
    model's name) with ``robot_model`` (a built-in name or a model mapping) or
    ``robot_model_file`` (TOML or JSON text). The same robot name and model is the same robot
    again; returns the campaign with its ``id`` and ``robot_id``. 507 when the disk is at its
    free-space reserve; 429 beyond ``[requests] campaigns_per_min``."""
    require_space(state, int(request.headers.get("content-length") or 0) + 4096, "campaign")
    state.per_minute["campaign"].take(request)
    robot = robot_for_campaign(state, body)
    return _out(state, state.store.create_campaign(body.name, int(robot["id"]), body.notes))


def _out(state: AppState, row: CampaignRow) -> CampaignOut:
    """The stored campaign with what identify needs of it (:class:`CampaignOut`): cached per
    robot and anchor count, so a poll of ``GET /campaigns`` computes nothing new."""
    need = state.min_samples.get(int(row["robot_id"]), len(row["anchors"]))
    out = cast(CampaignOut, dict(row))
    out["min_training_samples"] = need.training_samples
    out["min_samples_to_identify"] = need.samples
    out["recommended_training_samples"] = need.recommended_training_samples
    out["recommended_samples"] = need.recommended_samples
    return out


@router.get("/campaigns", summary="List campaigns (paginated)", dependencies=[ReadAuth])
def list_campaigns(
    state: State, request: Request, response: Response, page: PagedLarge
) -> list[CampaignOut]:
    """By id, ``limit`` per page (default and most 500) after ``after_id``; a full page has a
    ``Link: <…>; rel="next"`` header."""
    rows = state.store.list_campaigns(after_id=page.after_id, limit=page.limit)
    link_next(request, response, rows, page.limit)
    return [_out(state, r) for r in rows]


@router.get(
    "/campaigns/{campaign_id}",
    summary="One campaign",
    dependencies=[ReadAuth],
    responses=error_responses(404),
)
def get_campaign(state: State, campaign_id: CampaignId) -> CampaignOut:
    """With ``anchors`` (of the included samples), ``min_samples_to_identify`` (the fewest
    included samples an identification with the default options accepts),
    ``min_training_samples`` and ``recommended_samples`` (the count at which outlier
    screening works)."""
    return _out(state, state.store.campaign(campaign_id))


@router.post(
    "/campaigns/{campaign_id}/captures",
    status_code=status.HTTP_201_CREATED,
    summary="Manual capture",
    dependencies=[WriteAuth],
    responses={
        **error_responses(404),
        409: {
            "model": Error,
            "description": "Robot moving / not settled, over-range, pose already captured, "
            "joints_deg outside the joint limits of the campaign's robot model, joints_deg "
            "for a robot driver that reports its own angles",
        },
        503: {
            "model": Error,
            "description": "A device is down or stale; names the device and its last error",
        },
    },
)
async def capture(state: State, campaign_id: CampaignId, body: CaptureRequest) -> SampleOut:
    """Waits up to ``sampler.capture_timeout_s`` for the robot and the cable to settle, then
    stores the mean of the settled window and returns the stored sample. With the manual robot
    driver, ``joints_deg`` carries the joint angles [deg]."""
    campaign = state.store.campaign(campaign_id)
    if state.sampler is None:
        raise HTTPException(503, "sampler: not running")
    if body.joints_deg is not None:
        _check_limits(state, int(campaign["robot_id"]), body.joints_deg)
    if not body.repeat:
        _refuse_a_repeat(state, campaign_id, body.joints_deg)
    try:
        sample: SampleOut = await state.sampler.capture(
            campaign_id, anchor=body.anchor, joints_deg=body.joints_deg
        )
    except CaptureRejected as exc:
        raise HTTPException(
            exc.http_status,
            {"reason": exc.reason, "detail": exc.detail, "device": exc.device},
        ) from exc
    except ValueError as exc:  # joints_deg for a robot that reports its own: the cell's state
        raise HTTPException(409, str(exc)) from exc
    return sample


def _refuse_a_repeat(state: State, campaign_id: int, joints_deg: list[float] | None) -> None:
    """409 ``not_new_pose`` when the robot stands at a pose the campaign has captured
    already: auto capture's rule (:func:`calib.dataset.known_pose_index` within the sampler's
    ``auto_new_pose_deg``, every sample of the campaign, excluded ones too), checked on the
    angles sent (manual robot) or the newest paired reading. The page asks the operator and
    sends ``repeat`` to store it anyway."""
    assert state.sampler is not None
    q: list[float] | tuple[float, ...] | None = joints_deg
    if q is None:
        newest = state.sampler.recent_readings(0.0, 1)
        if not newest:
            return  # no reading yet: the capture itself says so
        q = newest[-1].joints_deg
    known = state.store.poses_deg(campaign_id)
    index = known_pose_index(known, q, state.settings.sampler.auto_new_pose_deg)
    if index is None:
        return
    rows = state.store.list_samples(campaign_id, limit=min(index + 1, 10_000))
    which = f"sample {rows[index]['id']}" if index < len(rows) else "a sample"
    detail = (
        f"the robot stands at the pose of {which} (every joint within "
        f"{state.settings.sampler.auto_new_pose_deg:g} deg); move it to a new pose, or "
        "confirm the repeat (repeat: true)"
    )
    raise HTTPException(409, {"reason": "not_new_pose", "detail": detail, "device": None})


def _check_limits(state: State, robot_id: int, joints_deg: list[float]) -> None:
    """The CSV import's checks (finite, within the model's joint limits) on one pose; the
    error names ``joints_deg[j]`` instead of the CSV column ``q{j+1}``. Outside the limits of
    the campaign's robot model is a 409 (a rule of the robot, not of the request's shape)."""
    try:
        pose = make_samples([joints_deg], [0.0])
        validate_joint_limits(pose, state.store.robot_model(robot_id))
    except SampleError as exc:
        j = JOINT_COLUMNS.index(exc.column) if exc.column in JOINT_COLUMNS else None
        loc: tuple[str | int, ...] = ("body", "joints_deg") + (() if j is None else (j,))
        field = "joints_deg" if j is None else f"joints_deg[{j}]"
        message = str(exc).split(": ", 1)[-1]
        if "outside the limits" in message:  # the campaign's robot model refuses it: 409
            raise HTTPException(409, f"{field}: {message}") from exc
        raise unprocessable(loc, f"{field}: {message}") from exc


@router.put(
    "/campaigns/{campaign_id}/auto-capture",
    summary="Auto capture on or off",
    dependencies=[WriteAuth],
    responses=error_responses(404, 503),
)
async def auto_capture(state: State, campaign_id: CampaignId, body: AutoCapture) -> CampaignOut:
    """On: the sampler captures once at each new settled pose, for this campaign only (it
    switches off any other campaign). The setting survives a daemon restart.

    Validated first (the body, the campaign, a running sampler), then stored (one
    transaction), then applied to the sampler; if the sampler refuses, the stored change is
    rolled back and the sampler put back as it was, so the database and the sampler agree.
    One switch at a time (a lock held from the store's write to the sampler's): parallel
    switches end with the database and the sampler naming the same campaign. The store's
    reads and writes run in a worker thread, the sampler's switch on the event loop that owns
    the sampler."""
    # Auto capture's one owner: daemon.autocapture.AutoCapture.
    if state.auto is None:
        state.store.campaign(campaign_id)  # 404 first
        raise HTTPException(503, "sampler: not running")
    try:
        row = await state.auto.switch(campaign_id, body.enabled, body.anchor)
    except SamplerUnavailable as exc:
        raise HTTPException(503, f"sampler: {exc}") from exc
    except SamplerRefused as exc:
        raise HTTPException(503, f"sampler: could not switch auto capture ({exc})") from exc
    return _out(state, row)


@router.get(
    "/campaigns/{campaign_id}/samples",
    summary="Samples as JSON (paginated), or CSV with ?format=csv",
    dependencies=[ReadAuth],
    responses={200: {"content": {"text/csv": {}}}, **error_responses(404, 429, 503)},
    response_model=list[SampleOut],
)
async def list_samples(
    state: State,
    request: Request,
    response: Response,
    campaign_id: CampaignId,
    page: Paged,
    format: str = Query("json", pattern="^(json|csv)$", description="json or csv"),
) -> list[SampleOut] | Response:
    """JSON: the samples with their std, count, timestamps and excluded flag, by id,
    ``limit`` per page (default 1000) after ``after_id``; a full page has a ``Link: <…>;
    rel="next"`` header. CSV: every included sample (not paginated) in the format
    ``cablecal identify`` reads, streamed: read from the store a page of rows at a time in a
    worker thread behind the check gate (``[requests] max_checks`` at once, 429 beyond the
    queue before the response starts) as the client reads."""
    if format == "csv":
        state.store.campaign(campaign_id)  # 404 before the gate
        pages = state.store.export_csv_pages(campaign_id)

        async def first() -> str:
            return await run_in_threadpool(next, pages)

        head = await offload(request, state.gates["check"], first, cancel_on_leave=False)
        return StreamingResponse(
            _rest(state, head, pages),
            media_type="text/csv",
            headers=download_headers(f"campaign-{campaign_id}.csv"),
        )
    rows = await run_in_threadpool(
        state.store.list_samples, campaign_id, after_id=page.after_id, limit=page.limit
    )
    link_next(request, response, rows, page.limit)
    return rows


async def _rest(state: AppState, head: str, pages: Iterator[str]) -> AsyncIterator[bytes]:
    """The streamed CSV export: the first page (read behind the gate before the response
    started), then each further page read from the store in a worker thread within one of the
    check gate's places (waiting, never refused: the response has started), one page held at
    a time however slowly the client reads."""
    yield head.encode()
    while True:
        async with state.gates["check"].slot(refuse=False):
            piece = await run_in_threadpool(next, pages, None)
        if piece is None:
            return
        yield piece.encode()


@router.post(
    "/campaigns/{campaign_id}/samples/import",
    status_code=status.HTTP_201_CREATED,
    summary="Import samples from CSV",
    dependencies=[WriteAuth],
    responses=error_responses(400, 404, 415, 429, 503, 507),
    response_model=ImportResult,
    openapi_extra={
        "requestBody": {"content": {"text/csv": {"schema": {"type": "string"}}}, "required": True}
    },
)
async def import_samples(state: State, campaign_id: CampaignId, request: Request) -> Response:
    """The request body is the CSV text (``Content-Type: text/csv``, else 415; at most
    20 MiB): header q1..q6 [deg] and L [mm], optional ``anchor``. All or nothing: an error
    gives 400 naming the row (file line, header = 1) and column, and nothing of the import is
    stored. Parsed and stored in a worker thread, so the event loop (the sampler,
    ``/health``) keeps running."""
    state.store.campaign(campaign_id)  # 404 before the body is read
    media_type = request.headers.get("content-type", "").split(";")[0].strip().lower()
    if media_type not in IMPORT_MEDIA_TYPES:
        raise HTTPException(
            415,
            f"Content-Type: expected text/csv (the CSV text as the body), got {media_type!r}"
            if media_type
            else "Content-Type: expected text/csv (the CSV text as the body)",
        )
    declared = request.headers.get("content-length")
    require_space(state, int(declared) if declared else MAX_IMPORT_BYTES, "import")
    state.per_minute["import"].take(request)  # 429 beyond [requests] imports_per_min
    chunks = [chunk async for chunk in request.stream()]  # the request guard bounds the size
    raw = b"".join(chunks)
    require_space(state, len(raw), "import")

    async def parse_and_store() -> bytes:
        return await run_in_threadpool(_import_csv, state, campaign_id, raw)

    # Behind the check gate (a 20 MiB import is seconds of work): 429 beyond its queue.
    body = await offload(request, state.gates["check"], parse_and_store, cancel_on_leave=False)
    return Response(body, status_code=201, media_type="application/json")


def _import_csv(state: AppState, campaign_id: int, raw: bytes) -> bytes:
    """Decode, parse, check and store a CSV import, and encode the :class:`ImportResult` (in a
    worker thread: half a million ids take a second to encode)."""
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise HTTPException(
            400, {"row": None, "column": None, "message": f"not UTF-8: {exc}"}
        ) from exc
    try:
        samples = parse_samples_csv(text)  # header, numbers, NaN, sensor range: row and column
        _check_printable(samples)
        ids = state.store.import_samples(campaign_id, samples)  # and the joint limits
    except SampleError as exc:
        raise HTTPException(
            400, {"row": exc.row, "column": exc.column, "message": str(exc)}
        ) from exc
    # The ImportResult, encoded in pieces: one json.dumps of a large import's ids would hold
    # the GIL, and so the event loop, for the whole encoding.
    pieces = [",".join(map(str, ids[k : k + 20_000])) for k in range(0, len(ids), 20_000)]
    return f'{{"imported":{len(ids)},"sample_ids":[{",".join(pieces)}]}}'.encode()


def _check_printable(samples: SampleSet) -> None:
    """The text columns hold printable text, as a name or an anchor sent as JSON must
    (:func:`daemon.api.text_rules.not_printable`); else a :class:`SampleError` naming the row."""
    for column, cells in (("anchor", samples.anchor), ("group", samples.group or ())):
        for text in set(cells):
            if why := not_printable(text):
                index = cells.index(text)
                row = int(samples.line[index]) if samples.line is not None else index + 2
                raise SampleError(f"{why}: only printable text is allowed", row=row, column=column)


@router.patch(
    "/samples/{sample_id}",
    summary="Exclude or include",
    dependencies=[WriteAuth],
    responses=error_responses(404),
)
def patch_sample(state: State, sample_id: SampleId, body: SamplePatch) -> SampleOut:
    return state.store.set_excluded(sample_id, body.excluded, body.reason)
