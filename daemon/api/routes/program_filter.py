"""Program filtering: a plant's own robot programs corrected with the robot's calibration.

``POST /robots/{id}/filter`` takes ``multipart/form-data``: one or more ``files`` parts (each
with its ``filename``) and an optional ``frames`` part (the ``--frames`` TOML). The multipart
body is split with the standard library's MIME parser (the bytes of each part exactly as
sent), the filter runs in a worker thread (:func:`calib.filter.run.filter_files`), never on
the event loop.
"""

from __future__ import annotations

import asyncio
import hashlib
import io
import json
import re
import zipfile
from collections.abc import Mapping
from datetime import UTC, datetime
from email import policy
from email.parser import BytesParser
from typing import Any, NamedTuple
from urllib.parse import quote

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


class Preview(NamedTuple):
    """What a filter run was made with: the robot and the calibration (the current
    identification's job id, its result id and date)."""

    robot_id: int
    robot: str
    robot_model: str
    calibration_id: int
    result_id: int
    calibration_date: str


def outputs_digest(outputs: Mapping[str, bytes]) -> str:
    """SHA-256 (hex) of the filtered files, names and bytes, in name order: the preview's
    digest, which the download must match."""
    h = hashlib.sha256()
    for name in sorted(outputs):
        body = outputs[name]
        h.update(f"{len(name)}:{name}:{len(body)}:".encode())
        h.update(body)
    return h.hexdigest()


def _filter(
    state: State,
    robot_id: int,
    raw: bytes,
    content_type: str,
    keep: bool,
    only: list[str] | None,
    expect_calibration: int | None,
) -> tuple[Any, dict[str, Any], Preview]:
    """Parse, filter (worker thread): the run, its summary (naming the robot, the
    calibration and the outputs' digest) and what it was made with. 409 when the current
    calibration is not ``expect_calibration``; 422 when no file could be read (every
    problem named); a bad file among good ones is named in the summary's ``errors``."""
    from calib.filter.correct import calibration_from_result
    from calib.filter.run import filter_files
    from calib.filter.sites import FilterInputError, parse_frames_toml

    files, frames_text = _parts(raw, content_type)
    row = state.store.accepted_result(robot_id)
    robot = state.store.robot(robot_id)
    made = Preview(
        robot_id,
        robot["name"],
        robot["model_name"],
        int(row["job_id"]),
        int(row["id"]),
        datetime.fromtimestamp(float(row["created_at"]), UTC).isoformat(timespec="seconds"),
    )
    if expect_calibration is not None and expect_calibration != made.calibration_id:
        raise HTTPException(
            409,
            f"robot {made.robot}: the calibration changed since the preview (identification "
            f"#{expect_calibration} was shown, #{made.calibration_id} of "
            f"{made.calibration_date} is current now); preview the files again",
        )
    result = row["result"]
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
    if run.errors and not run.outputs:
        raise unprocessable(("body", "files"), "; ".join(str(e) for e in run.errors))
    extra = {
        "robot_id": robot_id,
        "robot": made.robot,
        "robot_model": made.robot_model,
        "calibration_id": made.calibration_id,
        "calibration_result_id": made.result_id,
        "calibration_date": made.calibration_date,
        "digest": outputs_digest(run.outputs),
    }
    return run, run.summary(extra), made


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
    calibration_id: int | None = Query(
        None,
        ge=1,
        description="The calibration (identification id) the preview showed: 409 if the "
        "robot's current one is another",
    ),
    digest: str | None = Query(
        None,
        pattern="^[0-9a-f]{64}$",
        description="The preview's digest of the filtered files: 409 if the files differ",
    ),
) -> Any:
    """Every target of the uploaded programs (RAPID, URScript, and the other dialects of
    ``cablecal filter``) corrected for the robot's current calibration, each file changed
    only in its targets' numbers. Returns the filtered file (one file; the counts in the
    ``X-Filter-Counts`` header) or a zip of the files and ``filter-summary.json`` (several),
    or with ``dry_run`` the summary only (with ``calibration_id``, ``calibration_date``, the
    robot and the ``digest`` of the files). A download with the preview's ``calibration_id``
    and ``digest`` returns exactly what the preview showed, or 409 when the calibration or
    the files changed. Every output names the robot, the calibration and its date (the
    summary, the zip's name and comment, the ``X-Filter-*`` headers). A file that cannot be
    read is named in the summary's ``errors`` while the others are filtered; a 422 when no
    file can be read; 409 when the robot has no current calibration; at most
    :data:`MAX_FILES` files and the guard's body limit."""
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
    run, summary, made = await asyncio.to_thread(
        _filter,
        state,
        robot_id,
        b"".join(chunks),
        request.headers.get("content-type", ""),
        keep_joint_targets,
        wanted,
        calibration_id,
    )
    if dry_run:
        return summary
    if digest is not None and digest != summary["digest"]:
        raise HTTPException(
            409,
            f"robot {made.robot}: the filtered files differ from the preview (other files or "
            "options); preview the files again",
        )
    counts = json.dumps(summary["counts"], separators=(",", ":"))
    headers = {
        "X-Filter-Counts": counts,
        "X-Filter-Exit-Code": str(summary["exit_code"]),
        "X-Filter-Robot": quote(made.robot, safe=" "),
        "X-Filter-Calibration-Id": str(made.calibration_id),
        "X-Filter-Calibration-Date": made.calibration_date,
        "X-Filter-Digest": summary["digest"],
    }
    if len(run.outputs) == 1 and not run.errors:
        ((name, body),) = run.outputs.items()
        return Response(
            body,
            media_type="application/octet-stream",
            headers={**download_headers(name), **headers},
        )
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
        zf.comment = (
            f"cablecal filter: robot {made.robot} ({made.robot_model}), calibration "
            f"#{made.calibration_id} of {made.calibration_date}"
        ).encode()[:65535]
        for name, body in run.outputs.items():
            zf.writestr(name, body)
        zf.writestr(SUMMARY_NAME, json.dumps(summary, indent=2) + "\n")
    day = made.calibration_date[:10]
    zip_name = f"robot-{robot_id}-calibration-{made.calibration_id}-{day}-filtered.zip"
    return Response(
        buf.getvalue(),
        media_type="application/zip",
        headers={**download_headers(zip_name), **headers},
    )
