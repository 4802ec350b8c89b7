"""``make run`` (``python -m daemon.cli.demo serve``) with its output not a terminal (a pipe, a
log file): every line it prints stays whole, so the URL and the commands can be copied from a
log as they are (issue 27 item 10: the "try:" line was wrapped at 80 columns)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytestmark = [pytest.mark.slow, pytest.mark.timeout(90)]

ROOT = Path(__file__).resolve().parents[1]


def _children_of(state_root: Path) -> list[int]:
    """Processes whose command line names a path under ``state_root`` (the cell, the daemon)."""
    pids = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            cmd = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        if str(state_root) in cmd:
            pids.append(int(entry.name))
    return pids


def test_make_run_prints_whole_lines_to_a_pipe(tmp_path: Path) -> None:
    env = {**os.environ, "COLUMNS": "80", "CABLECAL_API_TOKEN": "pipe-test-token-" + "x" * 40}
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "daemon.cli.demo",
            "serve",
            "--port",
            "0",
            "--state-dir",
            str(tmp_path / "state"),
        ],
        cwd=ROOT,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    lines: list[str] = []
    try:
        assert proc.stdout is not None
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            line = proc.stdout.readline()
            if not line:
                break
            lines.append(line.rstrip("\n"))
            if line.startswith("Ctrl-C stops both"):
                break
    finally:
        time.sleep(1.0)  # inside its wait loop, where Ctrl-C stops the cell and the daemon
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        left = _children_of(tmp_path)
        for pid in left:  # never leave the cell or the daemon running
            os.kill(pid, signal.SIGKILL)
    assert left == [], "make run left its cell or daemon running"
    text = "\n".join(lines)
    tries = [x for x in lines if x.lstrip().startswith("try:")]
    assert len(tries) == 1, text
    # one line, longer than 80 columns, with the whole command in it
    assert "curl -H 'Authorization: Bearer pipe-test-token-" in tries[0], text
    assert tries[0].rstrip().endswith("/api/v1/status"), text
    assert len(tries[0]) > 80
    program = [x for x in lines if "robot program" in x]
    assert all(x.rstrip().endswith("runs it)") for x in program), text
