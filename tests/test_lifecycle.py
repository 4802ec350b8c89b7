"""The daemon's start and stop in the event log (daemon.process.lifecycle) and the child-process
set-up (daemon.process.workers), without starting the daemon."""

from __future__ import annotations

import os
import threading
from pathlib import Path

import pytest

from daemon.process import workers
from daemon.process.lifecycle import STOPPED, UNCLEAN, iso_utc, record_start, unclean_previous_run
from daemon.store import Store


def test_unclean_shutdown_only_after_a_start_without_a_stop(tmp_path: Path) -> None:
    with Store(tmp_path / "db.sqlite3") as store:
        assert record_start(store) is None  # first start ever
        first = store.list_events(kind="daemon_started")[-1]
        assert first["detail"] == {"pid": os.getpid()}
        store.record_event(STOPPED, None, "cablecal serve stopped")
        assert unclean_previous_run(store) is None
        assert record_start(store) is None  # after a clean stop
        second = store.list_events(kind="daemon_started")[-1]
        # No stop recorded: the next start finds the previous run unclean.
        assert unclean_previous_run(store) == second
        detail = record_start(store)
        assert detail == {
            "previous_started_at": second["t_wall"],
            "previous_started_iso": iso_utc(second["t_wall"]),
            "previous_pid": os.getpid(),
            "previous_event_id": second["id"],
        }
        unclean = store.list_events(kind=UNCLEAN)
        assert len(unclean) == 1
        assert iso_utc(second["t_wall"]) in unclean[0]["message"]
        kinds = [e["kind"] for e in store.list_events()]
        assert kinds[-2:] == [UNCLEAN, "daemon_started"]


def test_a_start_event_without_pid_is_reported_without_one(tmp_path: Path) -> None:
    with Store(tmp_path / "db.sqlite3") as store:
        store.record_event("daemon_started", None, "cablecal serve started")  # older daemon
        detail = record_start(store)
        assert detail is not None and detail["previous_pid"] is None
        assert "pid" not in store.list_events(kind=UNCLEAN)[0]["message"]


def test_iso_utc() -> None:
    assert iso_utc(0.0) == "1970-01-01T00:00:00Z"
    assert iso_utc(1_700_000_000.9) == "2023-11-14T22:13:20Z"


def test_the_main_process_has_no_parent_to_watch() -> None:
    assert workers.watch_parent() is None
    assert not any(t.name == "cablecal-parent-watch" for t in threading.enumerate())


def test_bad_worker_settings_are_refused() -> None:
    with pytest.raises(ValueError, match="nice"):
        workers.lower_priority(-1)
    with pytest.raises(ValueError, match="blas_threads"):
        workers.limit_threads(0)


def test_a_refused_nice_is_a_warning(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    calls: list[int] = []

    def nice(increment: int) -> int:
        calls.append(increment)
        if increment:
            raise PermissionError(1, "Operation not permitted")
        return 0

    monkeypatch.setattr(workers.os, "nice", nice)
    assert workers.lower_priority(10) == 0
    assert calls == [10, 0]
    assert "cannot lower the priority" in caplog.text
