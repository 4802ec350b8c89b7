"""Shared state and dependencies of the routes: the app state object, the auth checks, the
id path parameters and the pagination of list routes."""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Annotated, Any, Final

from fastapi import Depends, HTTPException, Path, Query, Request, Response, status
from fastapi.exceptions import RequestValidationError
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from daemon.api.http.guard import API_PREFIX, UNAUTHORIZED_DETAIL, token_matches
from daemon.api.http.offload import PerMinute, WorkGate
from daemon.api.min_samples import MinSamplesCache
from daemon.config import Settings
from daemon.jobs.manager import JobManager
from daemon.store import Store
from daemon.store.db import MAX_PAGE_ROWS
from daemon.store.space import MIB, check_space


@dataclass
class AppState:
    """Everything the routes use, built in the lifespan and stopped in reverse order.

    Attributes
    ----------
    settings : Settings
    token : str
        The bearer token of write routes (and of read routes unless ``public_reads``).
    store : Store
    jobs : JobManager
    min_samples : MinSamplesCache
        The samples identify needs, per robot and anchor count.
    sampler : daemon.sampler.Sampler or None
        None until the lifespan has started it.
    hold_check : daemon.monitors.holdcheck.HoldCheckMonitor or None
        None until the lifespan has started it.
    auto : daemon.monitors.autocapture.AutoCapture or None
        Auto capture's one owner (the store and the sampler kept in step); None until the
        lifespan has started the sampler.
    started_monotonic_s : float
        :func:`time.monotonic` at start-up [s].
    gates : dict of str to WorkGate
        The bounds of heavy request work by kind (:func:`daemon.api.http.offload.gates_of`).
    per_minute : dict of str to PerMinute
        Writes a minute by kind (:func:`daemon.api.http.offload.per_minute_of`).
    """

    settings: Settings
    token: str
    store: Store
    jobs: JobManager
    min_samples: MinSamplesCache
    sampler: Any = None
    hold_check: Any = None
    watch: Any = None  # daemon.monitors.watch.SensorWatch, None until the lifespan has started it
    auto: Any = None
    started_monotonic_s: float = field(default_factory=time.monotonic)
    gates: dict[str, WorkGate] = field(default_factory=dict)
    per_minute: dict[str, PerMinute] = field(default_factory=dict)


def require_space(state: AppState, payload_bytes: int, what: str) -> None:
    """Refuse (507) a write of about ``payload_bytes`` to the store that would leave less free
    space than the ``[requests] disk_reserve_mb`` reserve (:mod:`daemon.store.space`)."""
    reserve = int(state.settings.requests.disk_reserve_mb * MIB)
    check_space(state.settings.database_path.parent, reserve, payload_bytes, what)


def get_state(request: Request) -> AppState:
    """The :class:`AppState` of the running app."""
    state: AppState = request.app.state.cablecal
    return state


State = Annotated[AppState, Depends(get_state)]

_bearer = HTTPBearer(auto_error=False, description="Bearer token (CABLECAL_API_TOKEN)")


def _check(state: AppState, creds: HTTPAuthorizationCredentials | None) -> None:
    if creds is None or not token_matches(f"Bearer {creds.credentials}", state.token):
        raise HTTPException(
            status_code=status.HTTP_401_UNAUTHORIZED,
            detail=UNAUTHORIZED_DETAIL,
            headers={"WWW-Authenticate": "Bearer"},
        )


def require_write(
    state: State,
    creds: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)],
) -> None:
    """Every write route: the bearer token is required."""
    _check(state, creds)


def require_read(
    state: State,
    creds: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)],
) -> None:
    """Read routes: the token is required unless ``public_reads`` is set."""
    if not state.settings.public_reads:
        _check(state, creds)


WriteAuth = Depends(require_write)
ReadAuth = Depends(require_read)


# ------------------------------------------------------------------------------ ids, pages
#: Largest row id: 2**53 - 1, the largest integer a JSON number (an IEEE double) holds
#: exactly, so the schema's bound means the same to every client (2**63 - 1, SQLite's limit,
#: is not representable there); a larger id is a 422, never a 500.
MAX_ID: Final = 2**53 - 1


def _id(name: str) -> Any:
    return Path(ge=1, le=MAX_ID, description=f"{name} id")


def bound_path_ids(request: Request) -> None:
    """Every route (an app-wide dependency, run before the route's own parameters): a path
    parameter named ``*_id`` that is a whole number above :data:`MAX_ID` is a 422 naming it,
    never a 500 from SQLite. The routes also declare their ids with the aliases below, which
    put the same bound into the OpenAPI schema; this catches a route that forgot to."""
    for name, value in request.path_params.items():
        text = str(value)
        if name.endswith("_id") and text.isascii() and text.isdigit() and int(text) > MAX_ID:
            raise RequestValidationError(
                [
                    {
                        "loc": ("path", name),
                        "msg": f"{name}: must be at most {MAX_ID}",
                        "type": "less_than_equal",
                    }
                ]
            )


def _number_queries(app: Any, template: str, method: str) -> frozenset[str]:
    """The query parameters that the app's OpenAPI document declares as numbers (``type:
    number``, alone or in ``anyOf``) for ``method`` on ``template``; cached per app."""
    cache: dict[tuple[str, str], frozenset[str]] | None = getattr(app.state, "number_queries", None)
    if cache is None:
        cache = {}
        for path, operations in app.openapi().get("paths", {}).items():
            for verb, op in operations.items():
                names = set()
                for param in op.get("parameters", []) if isinstance(op, dict) else []:
                    schema = param.get("schema", {})
                    kinds = [schema, *schema.get("anyOf", [])]
                    if param.get("in") == "query" and any(k.get("type") == "number" for k in kinds):
                        names.add(param["name"])
                cache[(path, verb.upper())] = frozenset(names)
        app.state.number_queries = cache
    return cache.get((template, method), frozenset())


def finite_queries(request: Request) -> None:
    """Every route (an app-wide dependency): a query parameter declared as a number that
    spells NaN or ±Infinity (``nan``, ``inf``, ``-Infinity``, …) is a 422 naming it, as
    finite numbers are the rule of every body too (:class:`daemon.api.schemas.StrictBody`)."""
    from daemon.api.http.latency import route_label  # the template the route matched

    method = "GET" if request.method == "HEAD" else request.method
    names = _number_queries(request.app, route_label(request.scope, API_PREFIX), method)
    for name in names:
        for text in request.query_params.getlist(name):
            try:
                value = float(text)
            except ValueError:
                continue  # not a number at all: the route's own validation says so
            if not math.isfinite(value):
                raise RequestValidationError(
                    [
                        {
                            "loc": ("query", name),
                            "msg": f"{name}: must be a finite number, got {text[:40]!r}",
                            "type": "finite_number",
                        }
                    ]
                )


CampaignId = Annotated[int, _id("Campaign")]
SampleId = Annotated[int, _id("Sample")]
JobId = Annotated[int, _id("Identification")]
RobotId = Annotated[int, _id("Robot")]

#: Rows of a list page: the default and the most a client may ask for.
PAGE_DEFAULT: Final = 1000
PAGE_MAX: Final = MAX_PAGE_ROWS


@dataclass(frozen=True)
class Page:
    """A page of a list route: rows with ``id > after_id``, by id, at most ``limit``.

    The response is the JSON list of rows; when the page is full, a ``Link: <url>;
    rel="next"`` header gives the next page (``after_id`` = the last id on this page). No
    header: this was the last page.
    """

    after_id: int
    limit: int


def page(
    after_id: int = Query(
        0, ge=0, le=MAX_ID, description="Only rows with a larger id (the cursor of the next page)"
    ),
    limit: int = Query(
        PAGE_DEFAULT, ge=1, le=PAGE_MAX, description=f"Rows per page (at most {PAGE_MAX})"
    ),
) -> Page:
    """The ``after_id`` and ``limit`` query parameters of a list route."""
    return Page(after_id, limit)


Paged = Annotated[Page, Depends(page)]

#: Rows of a list page of large rows (campaigns with their notes, jobs with their options):
#: the most a client may ask for, and the default. 500 campaigns with the longest notes are
#: about 20 MB.
LARGE_PAGE_MAX: Final = 500


def large_page(
    after_id: int = Query(
        0, ge=0, le=MAX_ID, description="Only rows with a larger id (the cursor of the next page)"
    ),
    limit: int = Query(
        LARGE_PAGE_MAX,
        ge=1,
        le=LARGE_PAGE_MAX,
        description=f"Rows per page (at most {LARGE_PAGE_MAX})",
    ),
) -> Page:
    """The ``after_id`` and ``limit`` of a list route of large rows."""
    return Page(after_id, limit)


PagedLarge = Annotated[Page, Depends(large_page)]


def link_next(
    request: Request,
    response: Response,
    rows: Sequence[Mapping[str, Any]],
    limit: int,
    cursor: str = "after_id",
) -> None:
    """Set ``Link: <…?{cursor}=<last id>&limit=…>; rel="next"`` when the page is full."""
    if len(rows) < limit or not rows:
        return
    url = request.url.include_query_params(**{cursor: int(rows[-1]["id"]), "limit": limit})
    response.headers["Link"] = f'<{url.path}?{url.query}>; rel="next"'
