"""The REST API against its own OpenAPI schema, with Schemathesis (property-based, in-process
over ASGI): no server error and every response as the schema declares it (status code,
content type, body), with the token and without it.

Bounded and reproducible: 25 examples per operation, hypothesis ``derandomize`` (a fixed
seed derived from each test), no deadline. The app runs on the EMULATED-free FakeSampler of
test_service.py; the store, the job pool and identification are real.
"""

from __future__ import annotations

import atexit
import shutil
import tempfile
from collections import Counter
from pathlib import Path
from typing import Any

import schemathesis
from hypothesis import HealthCheck, settings
from schemathesis.checks import not_a_server_error
from schemathesis.specs.openapi.checks import (
    content_type_conformance,
    response_schema_conformance,
    status_code_conformance,
)
from test_service import AUTH, TOKEN, FakeSampler, _settings

from daemon.api.main import create_app

CHECKS = [
    not_a_server_error,
    status_code_conformance,
    content_type_conformance,
    response_schema_conformance,
]
EXAMPLES_PER_OPERATION = 25


def _app_and_schema() -> Any:
    """The app and its schema. The schema comes from ``app.openapi()`` (no request); the
    lifespan is started by Schemathesis' ASGI client at the first call, once, and stopped at
    exit. (``schemathesis.pytest.from_fixture`` fails on pytest 9 with 4.32: ``_nodeid``.)"""
    tmp = Path(tempfile.mkdtemp(prefix="cablecal-schemathesis-"))
    atexit.register(shutil.rmtree, tmp, ignore_errors=True)
    app = create_app(_settings(tmp), TOKEN, sampler_factory=FakeSampler)
    loaded = schemathesis.openapi.from_dict(app.openapi())
    loaded.app = app
    return loaded


schema = _app_and_schema()

_BOUNDED = settings(
    max_examples=EXAMPLES_PER_OPERATION,
    derandomize=True,
    deadline=None,
    suppress_health_check=list(HealthCheck),
    database=None,
)


#: Requests sent, per (token?, operation): printed at the end of the module (``-s``).
SENT: Counter[tuple[bool, str]] = Counter()


def teardown_module() -> None:
    """Print the counts; stop the app (its job pool) now rather than at interpreter exit."""
    from schemathesis.python import asgi

    asgi.shutdown_lifespans()
    for token in (True, False):
        ops = {op for t, op in SENT if t == token}
        n = sum(c for (t, _), c in SENT.items() if t == token)
        print(f"\nschemathesis {'with' if token else 'without'} token: {len(ops)} operations, "
              f"{n} requests, 0 failures")  # fmt: skip


@schema.parametrize()
@_BOUNDED
def test_api_with_token(case: Any) -> None:
    SENT[True, case.operation.label] += 1
    case.call_and_validate(headers=AUTH, checks=CHECKS)


@schema.parametrize()
@_BOUNDED
def test_api_without_token(case: Any) -> None:
    SENT[False, case.operation.label] += 1
    response = case.call_and_validate(checks=CHECKS)
    if case.path.startswith("/api/v1") and case.path != "/api/v1/health":
        assert response.status_code == 401, (case.method, case.path, response.status_code)
