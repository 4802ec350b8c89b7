"""A campaign's samples: the list (JSON or CSV), the CSV import, and one sample's
exclusion (``/samples/{sample_id}``)."""

from __future__ import annotations

from collections.abc import AsyncIterator, Iterator

from fastapi import APIRouter, HTTPException, Query, Request, Response, status
from fastapi.responses import StreamingResponse
from starlette.concurrency import run_in_threadpool

from calib.dataset import SampleError, SampleSet, parse_samples_csv
from daemon.api.deps import (
    AppState,
    CampaignId,
    Paged,
    ReadAuth,
    SampleId,
    State,
    WriteAuth,
    link_next,
    require_space,
)
from daemon.api.errors import error_responses
from daemon.api.http.downloads import download_headers
from daemon.api.http.guard import MAX_IMPORT_BYTES
from daemon.api.http.offload import offload
from daemon.api.schemas import ImportResult, SamplePatch
from daemon.api.text_rules import not_printable
from daemon.store import SampleRow

#: Content-Types a CSV import accepts (anything else, e.g. application/json, is a 415).
IMPORT_MEDIA_TYPES = frozenset({"text/csv"})

router = APIRouter(tags=["campaigns"], responses=error_responses(400, 401, 413, 422))


@router.get(
    "/campaigns/{campaign_id}/samples",
    summary="Samples as JSON (paginated), or CSV with ?format=csv",
    dependencies=[ReadAuth],
    responses={200: {"content": {"text/csv": {}}}, **error_responses(404, 429, 503)},
    response_model=list[SampleRow],
)
async def list_samples(
    state: State,
    request: Request,
    response: Response,
    campaign_id: CampaignId,
    page: Paged,
    format: str = Query("json", pattern="^(json|csv)$", description="json or csv"),
) -> list[SampleRow] | Response:
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
def patch_sample(state: State, sample_id: SampleId, body: SamplePatch) -> SampleRow:
    return state.store.set_excluded(sample_id, body.excluded, body.reason)
