"""Structured logging: JSON lines off a terminal, readable lines on one, context fields,
DeviceError frames, idempotent setup."""

from __future__ import annotations

import io
import json
import logging
import os
from collections.abc import Iterator
from datetime import datetime
from pathlib import Path
from typing import Any

import pytest

from daemon.process.logs import setup_logging
from drivers.errors import IndicatorCRCError


class FakeTTY(io.StringIO):
    def isatty(self) -> bool:
        return True


@pytest.fixture(autouse=True)
def restore_root_logger() -> Iterator[None]:
    root = logging.getLogger()
    handlers, level = list(root.handlers), root.level
    yield
    root.handlers[:] = handlers
    root.setLevel(level)
    logging.captureWarnings(False)


def lines(stream: io.StringIO) -> list[dict[str, Any]]:
    return [json.loads(line) for line in stream.getvalue().splitlines()]


def test_json_lines_when_not_a_tty() -> None:
    out = io.StringIO()
    setup_logging(stream=out)
    logging.getLogger("daemon.sampler").info(
        "capture %d stored",
        7,
        extra={"device": "indicator", "campaign_id": 3, "sample_id": 7, "job_id": None},
    )
    (line,) = lines(out)
    assert line["level"] == "INFO"
    assert line["logger"] == "daemon.sampler"
    assert line["msg"] == "capture 7 stored"
    assert line["device"] == "indicator"
    assert line["campaign_id"] == 3 and line["sample_id"] == 7
    assert "job_id" not in line  # None context is left out
    ts = datetime.fromisoformat(line["ts"])
    assert line["ts"].endswith("Z") and ts.utcoffset() is not None and not ts.utcoffset()


def test_human_lines_on_a_tty() -> None:
    out = FakeTTY()
    setup_logging(stream=out)
    logging.getLogger("daemon.service").warning(
        "job failed", extra={"job_id": 12, "frames_hex": [b"\x01\x03"]}
    )
    text = out.getvalue()
    assert "WARNING daemon.service: job failed [job_id=12]" in text
    assert "\n    01 03" in text
    with pytest.raises(json.JSONDecodeError):
        json.loads(text.splitlines()[0])


@pytest.mark.parametrize("forced", [True, False])
def test_forced_format(forced: bool) -> None:
    out = FakeTTY() if forced else io.StringIO()
    setup_logging(json_lines=forced, stream=out)
    logging.getLogger("x").warning("hello")
    first = out.getvalue().splitlines()[0]
    assert first.startswith("{") is forced


def test_device_error_adds_device_frames_and_traceback() -> None:
    out = io.StringIO()
    setup_logging(stream=out)
    frames = ("1.000000 tx 01 03 00 00 00 02 c4 0b", "1.020000 rx 01 03 04 00 01 86 a0 ff ff")
    try:
        raise IndicatorCRCError("indicator", "CRC mismatch", frames)
    except IndicatorCRCError:
        logging.getLogger("daemon.sampler").exception("poll failed", extra={"campaign_id": 2})
    (line,) = lines(out)
    assert line["device"] == "indicator"
    assert line["frames_hex"] == list(frames)
    assert line["error"] == "IndicatorCRCError"
    assert line["campaign_id"] == 2
    assert "Traceback" in line["exc_info"] and "CRC mismatch" in line["exc_info"]


def test_explicit_extras_win_over_the_exception() -> None:
    out = io.StringIO()
    setup_logging(stream=out)
    try:
        raise IndicatorCRCError("indicator", "bad", ["tx 01"])
    except IndicatorCRCError:
        logging.getLogger("x").exception(
            "poll failed",
            extra={"device": "indicator-2", "frames_hex": "rx ff", "error": "crc"},
        )
    (line,) = lines(out)
    assert (line["device"], line["frames_hex"], line["error"]) == ("indicator-2", ["rx ff"], "crc")


def test_plain_exception_and_unserialisable_extra() -> None:
    out = io.StringIO()
    setup_logging(stream=out)
    try:
        1 / 0  # noqa: B018
    except ZeroDivisionError:
        logging.getLogger("x").exception("boom", extra={"device": object()})
    (line,) = lines(out)
    assert line["error"] == "ZeroDivisionError"
    assert line["device"].startswith("<object object")
    assert "ZeroDivisionError" in line["exc_info"]


def test_idempotent_setup() -> None:
    first, second = io.StringIO(), io.StringIO()
    setup_logging(stream=first)
    setup_logging("DEBUG", stream=second)
    root = logging.getLogger()
    assert [h.get_name() for h in root.handlers].count("cablecal") == 1
    assert root.level == logging.DEBUG
    logging.getLogger("x").debug("once")
    assert first.getvalue() == ""
    assert [line["msg"] for line in lines(second)] == ["once"]


def test_level_names_and_numbers() -> None:
    setup_logging("warning", stream=io.StringIO())
    assert logging.getLogger().level == logging.WARNING
    setup_logging(logging.ERROR, stream=io.StringIO())
    assert logging.getLogger().level == logging.ERROR
    with pytest.raises(ValueError, match="level"):
        setup_logging("LOUD", stream=io.StringIO())


def test_syslog_priority_prefix_on_the_journal(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """systemd sets JOURNAL_STREAM=dev:inode of stderr; journald strips "<N>" and uses it as
    the entry's priority."""
    path = tmp_path / "journal"
    with path.open("w") as journal:
        st = os.fstat(journal.fileno())
        monkeypatch.setenv("JOURNAL_STREAM", f"{st.st_dev}:{st.st_ino}")
        setup_logging("DEBUG", stream=journal)
        log = logging.getLogger("x")
        log.debug("d")
        log.info("i")
        log.warning("w")
        log.error("e")
        log.critical("c")
    text = path.read_text().splitlines()
    assert [line[:4] for line in text] == ["<7>{", "<6>{", "<4>{", "<3>{", "<2>{"]
    assert json.loads(text[2][3:])["msg"] == "w"


def test_no_prefix_on_other_streams(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("JOURNAL_STREAM", "1:2")
    with (tmp_path / "log").open("w") as other:
        setup_logging(stream=other)
        logging.getLogger("x").warning("w")
    assert (tmp_path / "log").read_text().startswith("{")
