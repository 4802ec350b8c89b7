"""Program filtering: a plant's own robot programs corrected with the robot's calibration.

``POST /robots/{id}/filter`` takes ``multipart/form-data``: one or more ``files`` parts (each
with its ``filename``) and an optional ``frames`` part (the ``--frames`` TOML). The multipart
body is read as it streams under its limits (:mod:`daemon.api.http.multipart`: the bytes of each
part exactly as sent); the filter (:func:`calib.filter.run.filter_files`) runs in a worker
process of its own, at most ``[requests] max_filters`` at once (:mod:`daemon.api.http.offload`),
never on the event loop, and is killed when the client leaves. A preview (``dry_run``) names
the robot, the calibration and a digest of the filtered files; a download given them returns
exactly those files or a 409.
"""

from __future__ import annotations

import hashlib
import io
import json
import zipfile
from collections.abc import Mapping
from datetime import UTC, datetime
from typing import Any, NamedTuple
from urllib.parse import quote

from fastapi import APIRouter, HTTPException, Query, Request, Response
from fastapi.exceptions import RequestValidationError
from typing_extensions import TypedDict

from calib.programs.formats import LANGUAGES, filter_files_help
from daemon.api.deps import ReadAuth, RobotId, State, WriteAuth
from daemon.api.errors import error_responses, unprocessable
from daemon.api.http.downloads import download_headers
from daemon.api.http.guard import MAX_FILTER_BYTES
from daemon.api.http.multipart import FormPart, read_form
from daemon.api.http.offload import offload
from daemon.api.routes.robots.robots import model_maker
from daemon.api.text_rules import not_portable_file_name
from daemon.process.workers import run_in_child

router = APIRouter(tags=["apply"], responses=error_responses(401, 404, 409, 413, 422, 429, 503))

#: Most program files in one request.
MAX_FILES = 50
#: Longest ``only`` query value [characters].
MAX_ONLY_CHARS = 2000
SUMMARY_NAME = "filter-summary.json"


class LanguageOut(TypedDict):
    """One controller language of the languages' registry
    (:data:`calib.programs.formats.LANGUAGES`)."""

    name: str
    title: str
    suffix: str
    extensions: list[str]
    files: str
    line_ending: str


class LanguagesOut(TypedDict):
    """Every controller language, and the files the filter takes in the operator's words."""

    languages: list[LanguageOut]
    filter_files: str


@router.get(
    "/programs/languages",
    summary="The controller languages: names, file suffixes and line endings",
    dependencies=[ReadAuth],
)
def program_languages() -> LanguagesOut:
    """Per language (the order of ``--format``): its name, title, the suffix of a program
    cablecal writes, the extensions the filter reads, the files in the operator's words and
    the line ending of a written program (``CRLF`` for Fanuc's ``.LS``); the page lists the
    filter's files from here."""
    return {
        "languages": [
            {
                "name": lang.name,
                "title": lang.title,
                "suffix": lang.suffix,
                "extensions": list(lang.extensions),
                "files": lang.files,
                "line_ending": "CRLF" if lang.newline == "\r\n" else "LF",
            }
            for lang in LANGUAGES.values()
        ],
        "filter_files": filter_files_help(),
    }


def _files_and_frames(parts: list[FormPart]) -> tuple[list[tuple[str, bytes]], str | None]:
    """The ``files`` (name, bytes) and the ``frames`` text of the parts read.

    Raises
    ------
    RequestValidationError
        422 naming the part that is wrong.
    """
    files: list[tuple[str, bytes]] = []
    frames: str | None = None
    for part in parts:
        if part.name == "files":
            k = len(files)
            why = _not_a_program_name(part.filename or "", [f for f, _ in files])
            if why:
                raise unprocessable(("body", "files", k), f"files[{k}]: {why}")
            files.append((part.filename or "", bytes(part.data)))
        else:  # frames (the reader reads no other name, and at most one of it)
            try:
                frames = part.data.decode("utf-8")
            except UnicodeDecodeError:
                raise unprocessable(("body", "frames"), "frames: not UTF-8 text") from None
    if not files:
        raise unprocessable(("body", "files"), "files: at least one program file is required")
    return files, frames


def _not_a_program_name(name: str, taken: list[str]) -> str | None:
    """Why ``name`` cannot be a filter input's name (:func:`not_portable_file_name`), or None.
    KUKA's controller file ``$config.dat`` keeps its ``$`` (it is read, never written); two
    files of that name are two controller backups, said so."""
    from calib.programs.krl.filter import CONFIG_DAT

    if name.casefold() != CONFIG_DAT:
        return not_portable_file_name(name, taken)
    if other := next((n for n in taken if n.casefold() == CONFIG_DAT), None):
        return (
            f"{name!r} given twice (also {other!r}): two controller backups? Each backup's "
            "$config.dat belongs to its own programs: filter one backup at a time"
        )
    return None


#: Bytes of a file's start searched for a zero byte (no text program has one).
BINARY_SNIFF_BYTES = 65536


def binary_file_error(name: str, data: bytes) -> Any:
    """A :class:`calib.programs.inputs.FilterInputError` for a file that is not text (a zero byte
    in its first :data:`BINARY_SNIFF_BYTES`), else None."""
    from calib.programs.inputs import FilterInputError

    at = data.find(b"\x00", 0, BINARY_SNIFF_BYTES)
    if at < 0:
        return None
    return FilterInputError(
        name,
        f"not a text file: it holds binary data (a zero byte at byte {at + 1}); a robot "
        "program is text: give the controller's text file (a .ls, not a compiled .tp; the "
        "program files, not a zip or a backup archive)",
    )


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
    result: dict[str, Any],
    nominal: Any,
    files: list[tuple[str, bytes]],
    frames_text: str | None,
    keep: bool,
    only: list[str] | None,
    about: dict[str, Any],
) -> tuple[Any, dict[str, Any]]:
    """Filter (in a worker process, :func:`daemon.process.workers.run_in_child`): the run (its
    outputs and errors only) and its summary, naming the robot and the calibration
    (``about``) and the outputs' digest. 422 when no file could be read (every problem
    named); a bad file among good ones is named in the summary's ``errors``."""
    from calib.filter.correct import calibration_from_result
    from calib.filter.run import FilterRun, filter_files
    from calib.programs.krl.filter import is_config_dat
    from calib.programs.sites import FilterInputError, parse_frames_toml

    try:
        frames = None if frames_text is None else parse_frames_toml(frames_text, "frames")
    except FilterInputError as exc:
        raise unprocessable(("body", "frames"), str(exc)) from None
    try:
        cal = calibration_from_result(result, nominal)
    except ValueError as exc:
        raise HTTPException(
            409, f"robot {about['robot_id']}: calibration unusable: {exc}"
        ) from None
    binary = [e for name, data in files if (e := binary_file_error(name, data)) is not None]
    text_files = [(n, d) for n, d in files if n not in {e.file for e in binary}]
    run = filter_files(cal, text_files, frames=frames, keep_joint_targets=keep, only=only)
    run.errors[:0] = binary
    # $config.dat is the controller's own file: read (tools, bases, XHOME), never written
    run.outputs = {n: b for n, b in run.outputs.items() if not is_config_dat(n)}
    if run.errors and not run.sources:
        raise RequestValidationError(
            [
                {"loc": ("body", "files", e.file), "msg": str(e), "type": "value_error"}
                for e in run.errors
            ]
        )
    summary = run.summary({**about, "digest": outputs_digest(run.outputs)})
    for row, e in zip(summary["errors"], run.errors, strict=True):
        row["reason"] = e.message
    for row in summary["files"]:
        row.update(_file_notes(row, about))
    return FilterRun(outputs=run.outputs, errors=run.errors), summary


def _file_notes(row: Mapping[str, Any], about: Mapping[str, Any]) -> dict[str, Any]:
    """Per file of the summary: its format's ``maker``, a ``warning`` when that is not the
    robot's maker (``about["robot_maker"]``; also when the robot's maker is not known), and
    ``read_only`` for ``$config.dat``."""
    from calib.programs.formats import MAKER, TITLE
    from calib.programs.krl.filter import is_config_dat

    maker = MAKER.get(row["dialect"])
    robot_maker = about.get("robot_maker")
    warning = None
    if maker is not None and maker != robot_maker:
        whose = f"made by {robot_maker.upper()}" if robot_maker else "of a maker not known"
        warning = (
            f"{TITLE.get(row['dialect'], row['dialect'])} programs run on {maker.upper()} "
            f"controllers, but robot {about['robot']} is {whose} (model "
            f"{about['robot_model']}): check that they are this robot's before loading them"
        )
    return {"maker": maker, "warning": warning, "read_only": is_config_dat(row["file"])}


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
    """Every target of the uploaded programs (every language of ``GET /programs/languages``)
    corrected for the robot's current calibration, each file changed
    only in its targets' numbers. Returns the filtered file (one file; the counts in the
    ``X-Filter-Counts`` header) or a zip of the files and ``filter-summary.json`` (several),
    or with ``dry_run`` the summary only (with ``calibration_id``, ``calibration_date``, the
    robot and the ``digest`` of the files). A download with the preview's ``calibration_id``
    and ``digest`` returns exactly what the preview showed, or 409 when the calibration or
    the files changed. Every output names the robot, the calibration and its date (the
    summary, the zip's name and comment, the ``X-Filter-*`` headers). A file that cannot be
    read (a binary file, an empty one, another dialect's content) is named in the summary's
    ``errors`` (``reason``: the words without the file name) while the others are filtered;
    a 422 with one entry per file when no file can be read; 409 when the robot has no
    current calibration; at most :data:`MAX_FILES` files and the guard's body limit. KUKA's
    ``$config.dat`` is read, never written (not among the outputs; its ``files`` row says
    ``read_only``); a second one is refused naming both (two controller backups). Each
    ``files`` row names its format's ``maker`` and a ``warning`` when that is not the robot's
    maker (``robot_maker``: the model's ``[controller] maker`` or the library's ``# maker:``)."""
    # Before the body is read, and cheap (one row, nothing decoded: it runs on the event loop
    # for every request, a flood's too): 404 for an unknown robot, 409 without a calibration.
    if state.store.current_job_id(robot_id) is None:
        raise HTTPException(
            409, f"robot {robot_id}: no current calibration; accept an identification first"
        )
    parts = await read_form(
        request.stream(),
        request.headers.get("content-type", ""),
        {"files": MAX_FILES, "frames": 1},
        MAX_FILTER_BYTES,
    )
    files, frames_text = _files_and_frames(parts)
    wanted = [s.strip() for s in only.split(",") if s.strip()] if only is not None else None
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
    if calibration_id is not None and calibration_id != made.calibration_id:
        raise HTTPException(
            409,
            f"robot {made.robot}: the calibration changed since the preview (identification "
            f"#{calibration_id} was shown, #{made.calibration_id} of "
            f"{made.calibration_date} is current now); preview the files again",
        )
    result = row["result"]
    nominal = state.store.robot_model(robot_id)
    about = {
        "robot_id": robot_id,
        "robot": made.robot,
        "robot_model": made.robot_model,
        "calibration_id": made.calibration_id,
        "calibration_result_id": made.result_id,
        "calibration_date": made.calibration_date,
        "robot_maker": model_maker(nominal),
    }
    args = (result, nominal, files, frames_text, keep_joint_targets, wanted, about)
    nice, blas = state.settings.jobs.worker_nice, state.settings.jobs.worker_blas_threads
    run, summary = await offload(
        request,
        state.gates["filter"],
        lambda: run_in_child(_filter, *args, nice=nice, blas_threads=blas),
        time_limit_s=state.settings.requests.filter_timeout_s,
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
