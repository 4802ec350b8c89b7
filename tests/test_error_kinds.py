"""Issue 33 item 1: errors carry a kind and the HTTP status follows the kind
(:data:`daemon.api.errors.STATUS_OF_KIND`), never the message text.

An AST scan of the daemon's HTTP code finds a status chosen from a message: inside an
``except`` handler, a test (``in``, ``startswith``, ``endswith``, ``==``) on ``str(exc)``,
on ``exc.args`` or on a name assigned from them.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest
from fastapi import FastAPI
from fastapi.testclient import TestClient

from calib.csvtext import write_csv
from calib.dataset import SampleError, make_samples, validate_joint_limits
from calib.error_kinds import ErrorKind
from calib.models import builtin_model
from daemon.api.errors import STATUS_OF_KIND, ApiError, install
from daemon.api.program_download import download

ROOT = Path(__file__).resolve().parents[1]
#: The daemon's HTTP code: the API package (routes, plumbing).
HTTP_CODE = ("daemon/api",)
TEXT_TESTS = {"startswith", "endswith", "find", "index", "count"}


def _from_message(node: ast.AST, exc: str, names: set[str]) -> bool:
    """``node`` reads the message of exception ``exc``: ``str(exc)``, ``exc.args``, or a name
    assigned from one of them."""
    for sub in ast.walk(node):
        if isinstance(sub, ast.Name) and sub.id in names:
            return True
        if (
            isinstance(sub, ast.Call)
            and isinstance(sub.func, ast.Name)
            and sub.func.id in {"str", "repr", "format"}
            and any(isinstance(a, ast.Name) and a.id == exc for a in sub.args)
        ):
            return True
        if (
            isinstance(sub, ast.Attribute)
            and sub.attr == "args"
            and isinstance(sub.value, ast.Name)
            and sub.value.id == exc
        ):
            return True
    return False


def text_tests(tree: ast.AST) -> list[int]:
    """Lines where an ``except ... as exc`` handler tests its message's text."""
    found = []
    for handler in ast.walk(tree):
        if not isinstance(handler, ast.ExceptHandler) or handler.name is None:
            continue
        exc, names = handler.name, set()
        for stmt in handler.body:
            for sub in ast.walk(stmt):
                if isinstance(sub, ast.Assign) and _from_message(sub.value, exc, names):
                    names |= {t.id for t in sub.targets if isinstance(t, ast.Name)}
        for stmt in handler.body:
            for sub in ast.walk(stmt):
                if isinstance(sub, ast.Compare) and any(
                    isinstance(op, ast.In | ast.NotIn | ast.Eq | ast.NotEq) for op in sub.ops
                ):
                    if _from_message(sub, exc, names):
                        found.append(sub.lineno)
                elif (
                    isinstance(sub, ast.Call)
                    and isinstance(sub.func, ast.Attribute)
                    and sub.func.attr in TEXT_TESTS
                    and _from_message(sub.func.value, exc, names)
                ):
                    found.append(sub.lineno)
    return found


def test_no_route_picks_a_status_from_message_text() -> None:
    found = []
    for folder in HTTP_CODE:
        for path in sorted((ROOT / folder).rglob("*.py")):
            tree = ast.parse(path.read_text(encoding="utf-8"))
            found += [f"{path.relative_to(ROOT)}:{line}" for line in text_tests(tree)]
    assert found == [], f"status from message text (raise ApiError with a kind): {found}"


def test_the_scan_finds_a_status_from_text() -> None:
    code = """
try:
    f()
except ValueError as exc:
    message = str(exc)
    if message.startswith("anchor:"):
        raise HTTPException(404)
    if "outside" in str(exc):
        raise HTTPException(409)
    if exc.args[0] == "x":
        pass
    if exc.kind is ErrorKind.CONFLICT:  # the kind: fine
        pass
    raise HTTPException(422, f"format: {exc}")  # the message as the detail: fine
"""
    assert text_tests(ast.parse(code)) == [6, 8, 10]


def test_every_kind_has_one_status_and_the_handler_follows_it() -> None:
    assert set(STATUS_OF_KIND) == set(ErrorKind)
    app = FastAPI()
    install(app)

    @app.get("/fail/{kind}")
    def fail(kind: str) -> None:
        raise ApiError(ErrorKind(kind), f"{kind}: reworded at will", ("query", "x"))

    with TestClient(app) as client:
        for kind, status in STATUS_OF_KIND.items():
            r = client.get(f"/fail/{kind.value}")
            assert r.status_code == status, r.text
        r = client.get(f"/fail/{ErrorKind.INVALID.value}")
        assert r.json()["detail"] == [
            {"loc": ["query", "x"], "msg": "invalid: reworded at will", "type": "value_error"}
        ]
        assert client.get("/fail/conflict").json() == {"detail": "conflict: reworded at will"}


MODEL = builtin_model("hsr-jr680")
PLAN_COLUMNS = ("pose", "q1", "q2", "q3", "q4", "q5", "q6", "anchor")


LIMITS_DEG = MODEL.joint_limits_deg
assert LIMITS_DEG is not None
MID_DEG = LIMITS_DEG.mean(axis=1)  # (6,) the middle of each joint's range [deg]


def _plan(*rows: tuple[float, str]) -> str:
    """A plan CSV: one pose per row, ``q1`` as given [deg], the other joints in the middle of
    their range, at an anchor."""
    return write_csv(
        (
            {"pose": i + 1, **{f"q{j + 1}": float(MID_DEG[j]) for j in range(6)}, "q1": q1}
            | {"anchor": a}
            for i, (q1, a) in enumerate(rows)
        ),
        PLAN_COLUMNS,
    )


def _kind(csv_text: str, anchor: str | None) -> ErrorKind:
    with pytest.raises(ApiError) as info:
        download(
            csv_text,
            "krl",
            stem="p",
            model=MODEL,
            what="plan 1",
            dwell_s=1.0,
            settle_s=0.5,
            anchor=anchor,
        )
    return info.value.kind


def test_a_program_download_is_refused_by_the_kind_of_what_failed() -> None:
    two = _plan((10.0, "A"), (20.0, "B"))
    assert _kind(two, "Z") is ErrorKind.NOT_FOUND  # an anchor the plan lacks: 404
    assert _kind(two, None) is ErrorKind.CONFLICT  # several anchors, none picked: 409
    outside = float(LIMITS_DEG[0, 1]) + 5.0
    assert _kind(_plan((outside, "A")), "A") is ErrorKind.CONFLICT  # the robot's limits: 409
    mid = ",".join(f"{v:g}" for v in MID_DEG)
    flagged = f"q1,q2,q3,q4,q5,q6,flags\n{mid},no_solution\n"
    assert _kind(flagged, None) is ErrorKind.INVALID  # the file's form: 422
    ok = download(
        two, "krl", stem="p", model=MODEL, what="plan 1", dwell_s=1.0, settle_s=0.5, anchor="B"
    )
    assert ok.status_code == 200


def test_a_pose_outside_the_model_limits_is_a_conflict_and_a_bad_value_invalid() -> None:
    pose = [float(v) for v in MID_DEG]
    pose[2] = float(LIMITS_DEG[2, 0]) - 1.0
    with pytest.raises(SampleError) as info:
        validate_joint_limits(make_samples([pose], [0.0]), MODEL)
    assert info.value.kind is ErrorKind.CONFLICT and info.value.column == "q3"
    assert info.value.message.startswith("joint angle")  # no row and column in it
    with pytest.raises(SampleError) as info:
        make_samples([[0.0, 0.0, float("nan"), 0.0, 0.0, 0.0]], [0.0])
    assert info.value.kind is ErrorKind.INVALID
