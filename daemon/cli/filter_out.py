"""``cablecal filter --out DIR``: the filtered files and the summary as one set.

The set is written into a fresh temporary directory beside ``DIR`` (each file fsynced, with
its mode), which then takes ``DIR``'s place in one step: Linux's ``renameat2`` with
``RENAME_EXCHANGE`` swaps the two directories (the previous set, now under the temporary
name, is then removed), or a plain rename when ``DIR`` does not exist yet. A reader sees the
previous set or the new one, never a mix. An interrupted run (Ctrl-C, SIGTERM) removes its
temporary directory; one killed outright (SIGKILL, power loss) leaves it, and the next run
beside the same ``DIR`` removes it (its process is gone). Where ``renameat2`` is missing, the
previous set is renamed away first and the new one renamed in: between the two renames
``DIR`` is briefly absent.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import errno
import os
import shutil
import signal
import tempfile
from collections.abc import Iterator, Mapping
from pathlib import Path
from types import FrameType

#: Between the target's name and the process id in the temporary directory's name.
TMP_TAG = ".cablecal-filter-"
_AT_FDCWD = -100
_RENAME_EXCHANGE = 2


class OutDirError(OSError):
    """``DIR`` cannot take the set (the message says why)."""


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def default_file_mode() -> int:
    """The mode a new file gets under the process's umask (``0o666 & ~umask``)."""
    return 0o666 & ~_umask()


def _fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY | os.O_DIRECTORY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def remove_stale(out: Path) -> list[Path]:
    """Remove the temporary directories of killed runs beside ``out``; return them."""
    gone = []
    prefix = f".{out.name}{TMP_TAG}"
    with contextlib.suppress(OSError):
        for entry in out.parent.iterdir():
            if not entry.name.startswith(prefix) or not entry.is_dir():
                continue
            pid = entry.name[len(prefix) :].split("-", 1)[0]
            if pid.isdigit() and not _alive(int(pid)):
                shutil.rmtree(entry, ignore_errors=True)
                gone.append(entry)
    return gone


def _exchange(a: Path, b: Path) -> bool:
    """Swap two directories in one step; False where the system cannot."""
    name = ctypes.util.find_library("c")
    if name is None:
        return False
    libc = ctypes.CDLL(name, use_errno=True)
    fn = getattr(libc, "renameat2", None)
    if fn is None:
        return False
    rc = fn(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE)
    if rc == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.EINVAL, errno.ENOSYS, errno.ENOTSUP):
        return False
    raise OSError(err, os.strerror(err), str(b))


@contextlib.contextmanager
def _term_as_interrupt() -> Iterator[None]:
    """SIGTERM raises KeyboardInterrupt while the set is written (so it is cleaned up)."""

    def handler(signum: int, frame: FrameType | None) -> None:
        raise KeyboardInterrupt

    try:
        old = signal.signal(signal.SIGTERM, handler)
    except ValueError:  # not the main thread: leave signals alone
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)


def write_set(out: Path, files: Mapping[str, tuple[bytes, int]], marker: str) -> None:
    """Make ``out`` hold exactly ``files`` (name → (bytes, mode)), as described above.

    ``out`` must be absent, empty, or a previous set (holding ``marker``, the summary's
    name): a directory of other files is never replaced.

    Raises
    ------
    OutDirError
        ``out`` is not a directory, or holds files of something else.
    OSError
        Writing failed (the previous set is left as it was).
    """
    out = Path(os.path.abspath(out))
    if out.is_symlink() or (out.exists() and not out.is_dir()):
        raise OutDirError(f"{out} is not a directory")
    if out.is_dir() and any(out.iterdir()) and not (out / marker).is_file():
        raise OutDirError(
            f"{out} holds other files and no {marker}: give a new or empty directory "
            "(the filtered set replaces the directory's content)"
        )
    out.parent.mkdir(parents=True, exist_ok=True)
    remove_stale(out)
    dir_mode = (out.stat().st_mode & 0o7777) if out.is_dir() else 0o777 & ~_umask()
    with _term_as_interrupt():
        tmp = Path(tempfile.mkdtemp(dir=out.parent, prefix=f".{out.name}{TMP_TAG}{os.getpid()}-"))
        try:
            for name, (data, mode) in files.items():
                fd = os.open(tmp / name, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
                with os.fdopen(fd, "wb") as fh:
                    fh.write(data)
                    fh.flush()
                    os.fchmod(fh.fileno(), mode)
                    os.fsync(fh.fileno())
            os.chmod(tmp, dir_mode)
            _fsync_dir(tmp)
            if not out.exists():
                os.rename(tmp, out)
            elif not _exchange(tmp, out):
                old = Path(
                    tempfile.mkdtemp(dir=out.parent, prefix=f".{out.name}{TMP_TAG}{os.getpid()}-")
                )
                os.rename(out, old / "previous")
                os.rename(tmp, out)
                os.rename(old / "previous", tmp)
                old.rmdir()
            _fsync_dir(out.parent)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
