"""Shared state and dependencies of the routes: the app state object and the auth checks."""

from __future__ import annotations

import hmac
import time
from dataclasses import dataclass, field
from typing import Annotated, Any

from fastapi import Depends, HTTPException, Request, status
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from daemon.config import Settings
from daemon.jobs import JobManager
from daemon.store import Store


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
    sampler : daemon.sampler.Sampler or None
        None until the lifespan has started it.
    drift : daemon.drift.DriftMonitor or None
        None until the lifespan has started it.
    started_monotonic_s : float
        :func:`time.monotonic` at start-up [s].
    """

    settings: Settings
    token: str
    store: Store
    jobs: JobManager
    sampler: Any = None
    drift: Any = None
    started_monotonic_s: float = field(default_factory=time.monotonic)


def get_state(request: Request) -> AppState:
    """The :class:`AppState` of the running app."""
    state: AppState = request.app.state.cablecal
    return state


State = Annotated[AppState, Depends(get_state)]

_bearer = HTTPBearer(auto_error=False, description="Bearer token (CABLECAL_API_TOKEN)")


def _check(state: AppState, creds: HTTPAuthorizationCredentials | None) -> None:
    if creds is None or not hmac.compare_digest(creds.credentials.encode(), state.token.encode()):
        raise HTTPException(
            status_code=status.HTTP_401_UNAUTHORIZED,
            detail="missing or wrong bearer token (Authorization: Bearer <CABLECAL_API_TOKEN>)",
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
