"""The one error shape of the REST API, its handlers and its OpenAPI declarations.

Every error response is a JSON object with a ``detail`` key:

- **422** (a request that does not validate, whether pydantic or a route found it):
  ``{"detail": [{"loc": ["body", "name"], "msg": "...", "type": "..."}, ...]}``, FastAPI's
  validation-error list. ``loc`` starts with ``body``, ``path``, ``query`` or ``header``.
- **every other 4xx and 5xx**: ``{"detail": "<message>"}``, a string naming the field or the
  resource; two routes give an object instead, declared in their responses: a refused capture
  (409/503: ``{"reason", "detail", "device"}``) and a bad CSV import (400:
  ``{"row", "column", "message"}``).

:func:`error_responses` declares these in the OpenAPI schema, so every status a route can
return is documented with its body.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from fastapi import FastAPI, Request
from fastapi.encoders import jsonable_encoder
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from pydantic import BaseModel
from starlette.exceptions import HTTPException as StarletteHTTPException

from calib.error_kinds import ErrorKind
from daemon.api.http.allow import allow_header
from daemon.store import StoreInvalid, StoreNotFound
from daemon.store.space import NoSpace

#: REST names of the store's row kinds where they differ (a job is an "identification").
API_KINDS = {"job": "identification"}

#: Longest ``msg`` of a validation issue [characters]; longer ones are cut (no echoed input).
MAX_MESSAGE_CHARS = 500

#: The one table from an error's kind to its HTTP status: a route raises :class:`ApiError`
#: with the kind its error carries (or the check that failed), never a status picked from a
#: message's words.
STATUS_OF_KIND: dict[ErrorKind, int] = {
    ErrorKind.INVALID: 422,
    ErrorKind.NOT_FOUND: 404,
    ErrorKind.CONFLICT: 409,
}


class ApiError(Exception):
    """An error whose status is its ``kind``'s (:data:`STATUS_OF_KIND`): ``detail`` the
    message; for ``INVALID``, ``loc`` where in the request (a 422 in the validation shape)."""

    def __init__(self, kind: ErrorKind, detail: str, loc: Sequence[str | int] = ("body",)) -> None:
        super().__init__(detail)
        self.kind = kind
        self.detail = detail
        self.loc = tuple(loc)


class CaptureRejection(BaseModel):
    """Why a capture was refused (409/503)."""

    reason: str
    detail: str
    device: str | None = None


class ImportProblem(BaseModel):
    """Where a CSV import failed (400): file line (header = 1) and column, when known."""

    row: int | None
    column: str | None
    message: str


class Error(BaseModel):
    """Every error but 422: ``detail`` is a message (or, for a refused capture or a bad CSV
    import, an object)."""

    detail: str | CaptureRejection | ImportProblem


class ValidationIssue(BaseModel):
    """One problem of a request that does not validate."""

    loc: list[str | int]
    msg: str
    type: str


class ValidationErrors(BaseModel):
    """422: every problem found, FastAPI's validation-error list."""

    detail: list[ValidationIssue]


_DESCRIPTIONS = {
    400: "Body that cannot be read (not UTF-8); a bad CSV import names its row and column",
    401: "Missing or wrong bearer token",
    404: "No such resource (names it)",
    409: "Conflict with the resource's state",
    413: "Request body over the limit",
    415: "Request body of a Content-Type the route does not read (names the one expected)",
    422: "Validation error: the list of problems, each with its location",
    429: "Too many requests from this peer, or too much of this work running or waiting; "
    "retry after Retry-After seconds",
    503: "A device or the sampler is not available, or the daemon is shutting down",
    507: "Refused before anything was written: the disk's free space is at the reserve",
}


def error_responses(*codes: int) -> dict[int | str, dict[str, Any]]:
    """``responses=`` of a route or router: each code with its model and description."""
    return {
        code: {
            "model": ValidationErrors if code == 422 else Error,
            "description": _DESCRIPTIONS.get(code, "Error"),
        }
        for code in codes
    }


def unprocessable(loc: Sequence[str | int], msg: str) -> RequestValidationError:
    """A 422 raised by a route after pydantic accepted the body: same shape as pydantic's."""
    return RequestValidationError([{"loc": tuple(loc), "msg": msg, "type": "value_error"}])


def not_found_detail(exc: StoreNotFound) -> str:
    """The 404 ``detail``: ``"campaign 3: not found"``, ``"identification 9: not found"``,
    ``"robot 1: no accepted calibration yet"``."""
    return f"{API_KINDS.get(exc.kind, exc.kind)} {exc.id}: {exc.reason}"


def _text(value: object) -> str:
    """``str(value)`` that UTF-8 can encode (an unpaired surrogate, e.g. in an unknown key the
    client sent, becomes ``\\ud800``), cut to :data:`MAX_MESSAGE_CHARS`."""
    text = str(value)[:MAX_MESSAGE_CHARS]
    return text.encode("utf-8", "backslashreplace").decode("utf-8")


def _issues(errors: Sequence[Any]) -> list[dict[str, Any]]:
    """loc, msg and type of each error (not the input: it may be megabytes, or not JSON)."""
    out = []
    for e in errors:
        loc = [p if isinstance(p, int) else _text(p) for p in e.get("loc", ())]
        msg = _text(e.get("msg", ""))
        out.append({"loc": loc, "msg": msg, "type": str(e.get("type", "value_error"))})
    return out


def install(app: FastAPI) -> None:
    """The exception handlers that give every error the shape above."""

    @app.exception_handler(RequestValidationError)
    async def _invalid(request: Request, exc: RequestValidationError) -> JSONResponse:
        return JSONResponse({"detail": _issues(exc.errors())}, status_code=422)

    @app.exception_handler(StarletteHTTPException)
    async def _http(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        detail: Any = exc.detail
        if exc.status_code == 422 and not isinstance(detail, list):
            detail = [{"loc": ["body"], "msg": _text(detail), "type": "value_error"}]
        elif isinstance(detail, str):
            detail = _text(detail)
        headers = getattr(exc, "headers", None)
        if exc.status_code == 405:  # every method of the path, not only the first route's
            headers = {**(headers or {}), "Allow": allow_header(request.app, request.scope)}
        return JSONResponse(
            {"detail": jsonable_encoder(detail)}, status_code=exc.status_code, headers=headers
        )

    @app.exception_handler(ApiError)
    async def _kinded(request: Request, exc: ApiError) -> JSONResponse:
        """The status of the error's kind (:data:`STATUS_OF_KIND`), the body of that status."""
        status = STATUS_OF_KIND[exc.kind]
        if status == 422:
            issue = {"loc": list(exc.loc), "msg": _text(exc.detail), "type": "value_error"}
            return JSONResponse({"detail": [issue]}, status_code=status)
        return JSONResponse({"detail": _text(exc.detail)}, status_code=status)

    @app.exception_handler(StoreNotFound)
    async def _not_found(request: Request, exc: StoreNotFound) -> JSONResponse:
        """The one not-found path: whatever the store (or the job manager) cannot find is a
        404 ``{"detail": "<kind> <id>: not found"}``; the routes do not check first."""
        return JSONResponse({"detail": _text(not_found_detail(exc))}, status_code=404)

    @app.exception_handler(NoSpace)
    async def _no_space(request: Request, exc: NoSpace) -> JSONResponse:
        """The free-space guard refused a write before it began: 507 with the reason."""
        return JSONResponse({"detail": _text(exc)}, status_code=507)

    @app.exception_handler(StoreInvalid)
    async def _store_invalid(request: Request, exc: StoreInvalid) -> JSONResponse:
        """A value the schema let through but the store refuses: a 422, never a 500."""
        return JSONResponse(
            {"detail": [{"loc": ["body"], "msg": _text(exc), "type": "value_error"}]},
            status_code=422,
        )


__all__ = [
    "API_KINDS",
    "STATUS_OF_KIND",
    "ApiError",
    "Error",
    "ValidationErrors",
    "error_responses",
    "install",
    "not_found_detail",
    "unprocessable",
]
