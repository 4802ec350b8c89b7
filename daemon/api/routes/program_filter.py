"""Program filtering: a plant's own robot programs corrected with the robot's calibration.

``POST /robots/{id}/filter`` takes ``multipart/form-data``: one or more ``files`` parts (each
with its ``filename``) and an optional ``frames`` part (the ``--frames`` TOML). The multipart
body is split with the standard library's MIME parser (the bytes of each part exactly as
sent), the filter runs in a worker thread (:func:`calib.filter.run.filter_files`), never on
the event loop.
"""

from __future__ import annotations

import asyncio
import io
import json
import re
import zipfile
from email import policy
from email.parser import BytesParser
from typing import Any

from fastapi import APIRouter, HTTPException, Query, Request, Response

from daemon.api.deps import RobotId, State, WriteAuth
from daemon.api.downloads import download_headers
from daemon.api.errors import error_responses, unprocessable
from daemon.store import NO_CALIBRATION, StoreNotFound

router = APIRouter(tags=["apply"], responses=error_responses(401, 404, 409, 413, 422))

#: Most program files in one request.
MAX_FILES = 50
#: Longest ``only`` query value [characters].
MAX_ONLY_CHARS = 2000
#: A file name: no directory, no control characters, at most 128 characters.
_FILE_NAME = re.compile(r"[^/\\\x00-\x1f]{1,128}")
SUMMARY_NAME = "filter-summary.json"


def _parts(raw: bytes, content_type: str) -> tuple[list[tuple[str, bytes]], str | None]:
    """The ``files`` (name, bytes) and the ``frames`` text of a multipart body.

    Raises
    ------
    HTTPException
        422 naming the part that is wrong.
    """
    if (
        not content_type.lower().startswith("multipart/form-data")
        or "boundary=" not in content_type
    ):
        raise unprocessable(("body",), "body: expected multipart/form-data with files parts")
    head = f"Content-Type: {content_type}\r\nMIME-Version: 1.0\r\n\r\n"
    msg = BytesParser(policy=policy.HTTP).parsebytes(head.encode("latin-1", "replace") + raw)
    if not msg.is_multipart():
        raise unprocessable(("body",), "body: not a multipart body")
    files: list[tuple[str, bytes]] = []
    frames: str | None = None
    for k, part in enumerate(msg.iter_parts()):
        name = part.get_param("name", header="content-disposition")
        payload = part.get_payload(decode=True)
        data = payload if isinstance(payload, bytes) else b""
        if name == "files":
            filename = part.get_filename() or ""
            if not _FILE_NAME.fullmatch(filename) or filename in (".", ".."):
                raise unprocessable(
                    ("body", "files", k),
                    f"files[{k}]: file name {filename!r} "
                    "must be a plain name (no directory), 1..128 characters",
                )
            if any(filename == f for f, _ in files):
                raise unprocessable(("body", "files", k), f"files: {filename} given twice")
            files.append((filename, data))
        elif name == "frames":
            if frames is not None:
                raise unprocessable(("body", "frames"), "frames: given twice")
            try:
                frames = data.decode("utf-8")
            except UnicodeDecodeError:
                raise unprocessable(("body", "frames"), "frames: not UTF-8 text") from None
        else:
            raise unprocessable(
                ("body", str(name)), f"{name}: unknown part (expected files, frames)"
            )
    if not files:
        raise unprocessable(("body", "files"), "files: at least one program file is required")
    if len(files) > MAX_FILES:
        raise unprocessable(("body", "files"), f"files: {len(files)} files, at most {MAX_FILES}")
    return files, frames


def _filter(
    state: State, robot_id: int, raw: bytes, content_type: str, keep: bool, only: list[str] | None
) -> tuple[Any, dict[str, Any]]:
    """Parse, filter (worker thread): the run and its summary."""
    from calib.filter.correct import calibration_from_result
    from calib.filter.run import filter_files
    from calib.filter.sites import FilterInputError, parse_frames_toml

    files, frames_text = _parts(raw, content_type)
    result = state.store.accepted_result(robot_id)["result"]
    nominal = state.store.robot_model(robot_id)
    try:
        frames = None if frames_text is None else parse_frames_toml(frames_text, "frames")
    except FilterInputError as exc:
        raise unprocessable(("body", "frames"), str(exc)) from None
    try:
        cal = calibration_from_result(result, nominal)
    except ValueError as exc:
        raise HTTPException(409, f"robot {robot_id}: calibration unusable: {exc}") from None
    run = filter_files(cal, files, frames=frames, keep_joint_targets=keep, only=only)
    if run.errors:
        raise unprocessable(("body", "files"), "; ".join(str(e) for e in run.errors))
    return run, run.summary({"robot_id": robot_id, "robot": nominal.name})


@router.post(
    "/robots/{robot_id}/filter",
    summary="Filter robot programs with the robot's calibration",
    dependencies=[WriteAuth],
    responses={
        200: {
            "content": {
                "application/zip": {},
                "application/octet-stream": {},
                "application/json": {},
            }
        }
    },
    openapi_extra={
        "requestBody": {
            "required": True,
            "content": {
                "multipart/form-data": {
                    "schema": {
                        "type": "object",
                        "properties": {
                            "files": {
                                "type": "array",
                                "maxItems": MAX_FILES,
                                "items": {"type": "string", "format": "binary"},
                            },
                            "frames": {"type": "string", "format": "binary"},
                        },
                        "required": ["files"],
                    }
                }
            },
        }
    },
)
async def filter_programs(
    state: State,
    robot_id: RobotId,
    request: Request,
    dry_run: bool = Query(False, description="Return only the summary (JSON)."),
    keep_joint_targets: bool = Query(
        False, description="Leave joint targets (taught points) alone."
    ),
    only: str | None = Query(
        None, max_length=MAX_ONLY_CHARS, description="Correct only these targets: NAME,NAME,…"
    ),
) -> Any:
    """Every target of the uploaded programs (RAPID, URScript, and the other dialects of
    ``cablecal filter``) corrected for the robot's current calibration, each file changed
    only in its targets' numbers. Returns the filtered file (one file; the counts in the
    ``X-Filter-Counts`` header) or a zip of the files and ``filter-summary.json`` (several),
    or with ``dry_run`` the summary only. A file that cannot be read is a 422 naming it and
    its line; 409 when the robot has no current calibration; at most :data:`MAX_FILES`
    files and the guard's body limit."""
    state.store.robot_model(robot_id)  # 404 for an unknown robot before the body is read
    try:
        state.store.accepted_result(robot_id)
    except StoreNotFound as exc:
        if exc.reason == NO_CALIBRATION:
            raise HTTPException(
                409, f"robot {robot_id}: no current calibration; accept an identification first"
            ) from None
        raise
    chunks = [chunk async for chunk in request.stream()]  # the request guard bounds the size
    wanted = [s.strip() for s in only.split(",") if s.strip()] if only is not None else None
    run, summary = await asyncio.to_thread(
        _filter,
        state,
        robot_id,
        b"".join(chunks),
        request.headers.get("content-type", ""),
        keep_joint_targets,
        wanted,
    )
    if dry_run:
        return summary
    counts = json.dumps(summary["counts"], separators=(",", ":"))
    headers = {"X-Filter-Counts": counts, "X-Filter-Exit-Code": str(summary["exit_code"])}
    if len(run.outputs) == 1:
        ((name, body),) = run.outputs.items()
        return Response(
            body,
            media_type="application/octet-stream",
            headers={**download_headers(name), **headers},
        )
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
        for name, body in run.outputs.items():
            zf.writestr(name, body)
        zf.writestr(SUMMARY_NAME, json.dumps(summary, indent=2) + "\n")
    return Response(
        buf.getvalue(),
        media_type="application/zip",
        headers={**download_headers(f"robot-{robot_id}-filtered.zip"), **headers},
    )
