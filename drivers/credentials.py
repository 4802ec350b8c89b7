"""Controller credentials: from the environment or a file only readable by its owner.

A robot config never holds a password itself; it names where the password is
(``password_env``: an environment variable, ``password_file``: a file with mode 0600 or
stricter). :func:`read_secret` reads it into a :class:`pydantic.SecretStr`, whose ``repr`` and
``str`` are ``'**********'``: the value never reaches a log line, a status reply or an error
message (errors name the variable or the file, never the value).
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

from pydantic import SecretStr

#: The largest secret file read [bytes] (a password, not a document).
MAX_SECRET_BYTES = 4096


class CredentialsError(ValueError):
    """The credentials cannot be read (names the setting, the variable or the file)."""


def read_secret(env: str | None, file: Path | None, field: str) -> SecretStr:
    """The secret from ``file`` when given, else from the environment variable ``env``.

    ``file`` must be a regular file that neither its group nor others can read or write
    (mode 0600 or 0400); its content is taken without the trailing newline.

    Raises
    ------
    CredentialsError
        No source set, the variable is unset or empty, the file is missing, too large, empty,
        or its mode is looser than 0600. The message names ``field`` and the source.
    """
    if file is not None:
        try:
            st = file.stat()
        except OSError as exc:
            raise CredentialsError(f"{field}_file: cannot read {file}: {exc.strerror}") from None
        if not stat.S_ISREG(st.st_mode):
            raise CredentialsError(f"{field}_file: {file} is not a regular file")
        if st.st_mode & 0o077:
            raise CredentialsError(
                f"{field}_file: {file} has mode {stat.S_IMODE(st.st_mode):04o}; the group and "
                f"others must have no access (chmod 600 {file})"
            )
        if st.st_size > MAX_SECRET_BYTES:
            raise CredentialsError(f"{field}_file: {file} is larger than {MAX_SECRET_BYTES} bytes")
        try:
            value = file.read_text(encoding="utf-8").rstrip("\r\n")
        except (OSError, UnicodeDecodeError) as exc:
            raise CredentialsError(f"{field}_file: cannot read {file}: {exc}") from None
        if not value:
            raise CredentialsError(f"{field}_file: {file} is empty")
        return SecretStr(value)
    if env:
        value = os.environ.get(env, "")
        if not value:
            raise CredentialsError(
                f"{field}_env: the environment variable {env} is unset or empty "
                f"(or set {field}_file to a file with mode 0600)"
            )
        return SecretStr(value)
    raise CredentialsError(f"{field}: set {field}_env or {field}_file")


def write_secret(path: Path, value: str) -> Path:
    """Write ``value`` to ``path`` with mode 0600 (created so; never world-readable)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        f.write(value + "\n")
    os.chmod(path, 0o600)
    return path
