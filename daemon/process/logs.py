"""Logging setup: JSON lines for the journal and log shippers, readable lines on a terminal.

Under systemd stderr goes to the journal (``journalctl -u cablecal``); it is not a TTY, so each
record is one JSON object per line::

    {"ts": "2025-03-04T10:15:02.311Z", "level": "WARNING", "logger": "daemon.sampler",
     "msg": "indicator poll failed", "device": "indicator", "campaign_id": 3,
     "error": "IndicatorCRCError", "frames_hex": ["12.5 tx 01 03 00 00 00 02 c4 0b", "..."]}

On the journal (stderr is the stream systemd names in ``JOURNAL_STREAM``) each line starts
with the syslog priority, ``<4>{...}``: journald strips it and files the entry at that
priority, so ``journalctl -u cablecal -p warning`` shows warnings and errors only.

Context goes in ``extra=``: :data:`CONTEXT_FIELDS` are copied to the line when present. When
the record carries an exception that is a :class:`drivers.errors.DeviceError`, its device and
last frames are added even if the caller did not pass them, so every logged device error
shows the bytes on the wire.
"""

from __future__ import annotations

import io
import json
import logging
import os
import sys
from collections.abc import Iterable
from datetime import UTC, datetime
from typing import IO, Any

#: ``extra=`` keys copied to every log line that has them.
CONTEXT_FIELDS = ("device", "campaign_id", "job_id", "sample_id", "frames_hex", "error")

#: Marks the handler :func:`setup_logging` installs, so a second call replaces it.
_HANDLER_NAME = "cablecal"


#: logging level → syslog priority (the ``<N>`` prefix journald understands).
_SYSLOG_PRIORITY = {
    logging.CRITICAL: 2,
    logging.ERROR: 3,
    logging.WARNING: 4,
    logging.INFO: 6,
    logging.DEBUG: 7,
}


def _syslog_priority(levelno: int) -> int:
    for level, priority in _SYSLOG_PRIORITY.items():  # highest level first
        if levelno >= level:
            return priority
    return 7


def is_journal_stream(stream: IO[str]) -> bool:
    """True when ``stream`` is the journal connection systemd set up (``JOURNAL_STREAM``
    holds its ``device:inode``)."""
    expected = os.environ.get("JOURNAL_STREAM", "")
    dev, _, ino = expected.partition(":")
    try:
        st = os.fstat(stream.fileno())
        return (st.st_dev, st.st_ino) == (int(dev), int(ino))
    except (AttributeError, OSError, ValueError, io.UnsupportedOperation):
        return False


def _iso_utc(created: float) -> str:
    """``record.created`` → ``2025-03-04T10:15:02.311Z``."""
    stamp = datetime.fromtimestamp(created, tz=UTC).isoformat(timespec="milliseconds")
    return stamp.replace("+00:00", "Z")


def _frames(value: Any) -> list[str]:
    """``frames_hex`` as a list of strings; bytes are dumped as spaced hex."""
    if isinstance(value, str | bytes | bytearray):
        value = [value]
    if not isinstance(value, Iterable):
        return [str(value)]
    return [bytes(v).hex(" ") if isinstance(v, bytes | bytearray) else str(v) for v in value]


def record_context(record: logging.LogRecord) -> dict[str, Any]:
    """The :data:`CONTEXT_FIELDS` of ``record``, completed from a DeviceError in exc_info."""
    ctx = {k: getattr(record, k) for k in CONTEXT_FIELDS if getattr(record, k, None) is not None}
    exc = record.exc_info[1] if record.exc_info else None
    if exc is not None:
        # Duck-typed so this module does not import the drivers (DeviceError has both).
        device = getattr(exc, "device", None)
        frames = getattr(exc, "frames_hex", None)
        if "device" not in ctx and isinstance(device, str):
            ctx["device"] = device
        if "frames_hex" not in ctx and frames:
            ctx["frames_hex"] = frames
        ctx.setdefault("error", type(exc).__name__)
    if "frames_hex" in ctx:
        ctx["frames_hex"] = _frames(ctx["frames_hex"])
    return ctx


class JsonLinesFormatter(logging.Formatter):
    """One JSON object per record: ts (ISO 8601 UTC), level, logger, msg, context, exc_info.

    Parameters
    ----------
    syslog_prefix : bool
        Start each line with ``<priority>`` for journald.
    """

    def __init__(self, syslog_prefix: bool = False) -> None:
        super().__init__()
        self.syslog_prefix = syslog_prefix

    def format(self, record: logging.LogRecord) -> str:
        line: dict[str, Any] = {
            "ts": _iso_utc(record.created),
            "level": record.levelname,
            "logger": record.name,
            "msg": record.getMessage(),
        }
        line.update(record_context(record))
        if record.exc_info:
            line["exc_info"] = self.formatException(record.exc_info)
        if record.stack_info:
            line["stack_info"] = self.formatStack(record.stack_info)
        # ASCII only: a name or a note with a bidi override or a line separator cannot
        # reorder or split a log line on a terminal or in the journal.
        text = json.dumps(line, ensure_ascii=True, default=str)
        return f"<{_syslog_priority(record.levelno)}>{text}" if self.syslog_prefix else text


class HumanFormatter(logging.Formatter):
    """``10:15:02.311 WARNING daemon.sampler: msg [device=indicator campaign_id=3]`` plus the
    frames and the traceback on the following lines."""

    def format(self, record: logging.LogRecord) -> str:
        ts = datetime.fromtimestamp(record.created).strftime("%H:%M:%S")
        ctx = record_context(record)
        frames = ctx.pop("frames_hex", [])
        text = f"{ts}.{int(record.msecs):03d} {record.levelname:<7} {record.name}: "
        text += record.getMessage()
        if ctx:
            text += " [" + " ".join(f"{k}={v}" for k, v in ctx.items()) + "]"
        for frame in frames:
            text += f"\n    {frame}"
        if record.exc_info:
            text += "\n" + self.formatException(record.exc_info)
        if record.stack_info:
            text += "\n" + self.formatStack(record.stack_info)
        # ASCII only, as the JSON lines: any other character as a backslash escape.
        return text.encode("ascii", "backslashreplace").decode("ascii")


def setup_logging(
    level: str | int = "INFO",
    json_lines: bool | None = None,
    *,
    stream: IO[str] | None = None,
) -> logging.Handler:
    """Configure the root logger; calling it again replaces the previous setup.

    Parameters
    ----------
    level : str or int
        Root level, a name (``"DEBUG"``, ``"info"``) or a number.
    json_lines : bool, optional
        True for JSON lines, False for human-readable lines; None (default) chooses JSON
        when ``stream`` is not a terminal (under systemd, in a container, piped to a file).
        JSON lines to the journal carry a ``<priority>`` prefix (see the module docstring).
    stream : text stream, optional
        Where to write; default ``sys.stderr`` (as it is at call time).

    Returns
    -------
    logging.Handler
        The installed handler (one per process, named ``"cablecal"``).

    Notes
    -----
    Loggers that have handlers of their own (uvicorn's, when it is given a ``log_config``)
    are left alone; run uvicorn with ``log_config=None`` so its records reach this handler.
    """
    if isinstance(level, str):
        resolved = logging.getLevelNamesMapping().get(level.upper())
        if resolved is None:
            raise ValueError(f"level: expected a logging level name, got {level!r}")
        level = resolved
    out = sys.stderr if stream is None else stream
    if json_lines is None:
        isatty = getattr(out, "isatty", None)
        json_lines = not (callable(isatty) and isatty())
    handler = logging.StreamHandler(out)
    handler.set_name(_HANDLER_NAME)
    handler.setFormatter(
        JsonLinesFormatter(syslog_prefix=is_journal_stream(out)) if json_lines else HumanFormatter()
    )
    root = logging.getLogger()
    for old in [h for h in root.handlers if h.get_name() == _HANDLER_NAME]:
        root.removeHandler(old)
        old.close()
    root.addHandler(handler)
    root.setLevel(level)
    logging.captureWarnings(True)
    return handler
