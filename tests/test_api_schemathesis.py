"""The REST API against its own OpenAPI schema, with Schemathesis (property-based, in-process
over ASGI): no server error, every response as the schema declares it (status code,
content type, body), and no request the schema allows refused as invalid (400/413/415/422:
``positive_data_acceptance``, but for the two file-format bodies of :func:`_file_format_body`),
with the token and without it.

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

import pytest
import schemathesis
from hypothesis import HealthCheck, settings
from schemathesis.checks import not_a_server_error
from schemathesis.generation import GenerationMode
from schemathesis.specs.openapi.checks import (
    content_type_conformance,
    negative_data_rejection,
    positive_data_acceptance,
    response_schema_conformance,
    status_code_conformance,
)
from test_service import AUTH, TOKEN, FakeSampler, _settings

from daemon.api.http.guard import UNAUTHORIZED_DETAIL
from daemon.api.main import create_app

#: One operation's 25 examples [s]: the plan operation computes up to 25 plans (72 s on an idle
#: 2-core machine), over the suite's 120 s default when another process shares the cores.
pytestmark = pytest.mark.timeout(360)

CHECKS = [
    not_a_server_error,
    status_code_conformance,
    content_type_conformance,
    response_schema_conformance,
    positive_data_acceptance,  # a request the schema allows is not refused (400/413/415/422)
    negative_data_rejection,  # a request the schema forbids is refused (a 4xx)
]
EXAMPLES_PER_OPERATION = 25
#: One request's limit [s]: a valid plan request computes a plan (bounded by the route's
#: limits), which on a loaded 2-core machine can take longer than Schemathesis' default 10 s.
REQUEST_TIMEOUT_S = 60


def _app_and_schema() -> Any:
    """The app and its schema. The schema comes from ``app.openapi()`` (no request); the
    lifespan is started by Schemathesis' ASGI client at the first call, once, and stopped at
    exit. (``schemathesis.pytest.from_fixture`` fails on pytest 9 with 4.32: ``_nodeid``.)"""
    tmp = Path(tempfile.mkdtemp(prefix="cablecal-schemathesis-"))
    atexit.register(shutil.rmtree, tmp, ignore_errors=True)
    app = create_app(_settings(tmp), TOKEN, sampler_factory=FakeSampler)
    loaded = schemathesis.openapi.from_dict(app.openapi())
    loaded.app = app
    # Both: requests the schema allows and requests it forbids, in the same example budget.
    # Exemptions from negative_data_rejection, each with its reason:
    # - allow_extra_parameters=False: an unknown query parameter is ignored, not refused (as
    #   HTTP APIs commonly do: a browser's or a proxy's cache-buster must not break a read),
    #   so "a parameter the schema lacks" is not invalid data here;
    # - with_security_parameters=False: the Authorization header is the test's to set (the run
    #   with the token adds it to every call, the run without checks the 401 of every guarded
    #   operation), so "Authorization missing" is not a negative case either.
    loaded.config.generation.update(
        modes=[GenerationMode.POSITIVE, GenerationMode.NEGATIVE],
        allow_extra_parameters=False,
        with_security_parameters=False,
    )
    return loaded


schema = _app_and_schema()

_BOUNDED = settings(
    max_examples=EXAMPLES_PER_OPERATION,
    derandomize=True,
    deadline=None,
    suppress_health_check=list(HealthCheck),
    database=None,
)


#: Requests sent and failed, per (token?, operation): printed at the end of the module (``-s``).
SENT: Counter[tuple[bool, str]] = Counter()
FAILED: Counter[tuple[bool, str]] = Counter()
#: Requests the schema forbids (negative mode), per token?.
NEGATIVE: Counter[bool] = Counter()


def teardown_module() -> None:
    """Print the counts; stop the app (its job pool) now rather than at interpreter exit."""
    from schemathesis.python import asgi

    asgi.shutdown_lifespans()
    for token in (True, False):
        ops = {op for t, op in SENT if t == token}
        n = sum(c for (t, _), c in SENT.items() if t == token)
        bad = {op for t, op in FAILED if t == token}
        print(
            f"\nschemathesis {'with' if token else 'without'} token: {len(ops)} operations, "
            f"{n} requests ({NEGATIVE[token]} the schema forbids), "
            f"{len(bad)} failing operations"
        )


#: Operations whose body has rules between its fields that JSON Schema cannot state (open,
#: issue 21): a plan's ``anchor_uncertainty_mm`` must leave an extension range within
#: ``extension_mm``, ``candidates`` must be enough for ``n`` (a 422 naming the option).
CROSS_FIELD_RULES = frozenset({"POST /api/v1/campaigns/{campaign_id}/plan"})
#: Operations whose body is checked against the robot's own model, which the schema (one for
#: every robot) cannot state: check poses within that model's joint limits (a 422 naming the
#: pose and joint).
MODEL_RULES = frozenset({"PUT /api/v1/robots/{robot_id}/check-poses"})


def _file_format_body(case: Any) -> bool:
    """A body whose rules are a file format's, not the schema's: a CSV import (header, numbers,
    sensor range, joint limits: a 400 naming row and column), robot programs to filter (a 422
    naming the file and line) and an uploaded robot model (the
    model file format of ``--robot``: a 422 naming the key), and the :data:`CROSS_FIELD_RULES`
    and :data:`MODEL_RULES` operations. Schemathesis' valid data is not valid there, so it is
    not held to positive_data_acceptance; every other check applies."""
    if case.operation.label in CROSS_FIELD_RULES | MODEL_RULES:
        return True
    if case.operation.label in (
        "POST /api/v1/campaigns/{campaign_id}/samples/import",
        "POST /api/v1/robots/{robot_id}/filter",
    ):  # program files
        return True
    body = case.body if isinstance(case.body, dict) else {}
    if case.operation.label == "POST /api/v1/robots":  # a model file; one of model, model_file
        return True
    # A campaign's robot: a model mapping or file (the model file format), an existing robot
    # (robot_id takes no model), or a robot name another model's robot may hold (a 409):
    # rules of the stored robots and of the file format, not of the schema.
    return case.operation.label == "POST /api/v1/campaigns" and (
        isinstance(body.get("robot_model"), dict)
        or any(k in body for k in ("robot_model_file", "robot_id", "robot"))
    )


def _run(case: Any, token: bool) -> Any:
    SENT[token, case.operation.label] += 1
    if case.meta is not None and case.meta.generation.mode.is_negative:
        NEGATIVE[token] += 1
    checks = [c for c in CHECKS if c is not positive_data_acceptance or not _file_format_body(case)]
    try:
        return case.call_and_validate(
            headers=AUTH if token else None, checks=checks, timeout=REQUEST_TIMEOUT_S
        )
    except BaseException:
        FAILED[token, case.operation.label] += 1
        raise


@schema.parametrize()
@_BOUNDED
def test_api_with_token(case: Any) -> None:
    _run(case, token=True)


@schema.parametrize()
@_BOUNDED
def test_api_without_token(case: Any) -> None:
    response = _run(case, token=False)
    # OPTIONS is public (it tells no more than this schema): 204 with Allow, token or not.
    if (
        case.path.startswith("/api/v1")
        and case.path != "/api/v1/health"
        and case.method.upper() != "OPTIONS"
    ):
        assert response.status_code == 401, (case.method, case.path, response.status_code)
        assert response.json() == {"detail": UNAUTHORIZED_DETAIL}


def test_both_runs_cover_every_operation_and_every_guarded_one_documents_401() -> None:
    """Both runs above are parametrized over every operation of the schema (one test each),
    and every operation under /api/v1 but /health declares the 401 the run without the token
    expects. (A run stopped early, e.g. by ``-x``, prints fewer operations at the end.)"""
    ops = [op.ok() for op in schema.get_all_operations()]
    spec = schema.app.openapi()["paths"]
    declared = {(path, method.upper()) for path, item in spec.items() for method in item}
    assert {(op.path, op.method.upper()) for op in ops} == declared
    assert len([p for p, _ in declared if p.startswith("/api/v1/")]) >= 25
    for op in ops:
        if op.path.startswith("/api/v1") and op.path != "/api/v1/health":
            assert "401" in op.definition.raw["responses"], op.label
