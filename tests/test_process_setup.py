"""daemon.process.blas: the numeric process set-up every cablecal command gets before numpy
loads."""

from __future__ import annotations

import platform
import subprocess
import sys

import pytest

GLIBC = sys.platform.startswith("linux") and platform.libc_ver()[0] == "glibc"


@pytest.mark.skipif(not GLIBC, reason="mallopt is glibc's")
def test_steady_heap_takes_on_glibc_and_the_cli_sets_it_up() -> None:
    # In a child: the thresholds are process-wide, and the test process must not keep them.
    code = (
        "import daemon.process.blas as b, daemon.cli, os; "
        "print(b.steady_heap(), os.environ['OPENBLAS_NUM_THREADS'])"
    )
    env = {"PATH": "/usr/bin:/bin"}
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, env=env
    )
    assert out.stdout.split() == ["True", "1"]


def test_steady_heap_changes_nothing_where_it_cannot_apply(monkeypatch: pytest.MonkeyPatch) -> None:
    import daemon.process.blas as b

    monkeypatch.setattr(b.sys, "platform", "darwin")
    assert b.steady_heap() is False
