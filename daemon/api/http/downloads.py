"""The ``Content-Disposition`` header of every download (model files, reports, CSV exports,
plans): one helper, so no route puts a user's text into a header by hand.

RFC 6266 with the RFC 5987 extended parameter: ``attachment; filename="<ascii>";
filename*=UTF-8''<percent-encoded>``. The quoted ``filename`` is an ASCII fallback for old
clients: every character outside printable ASCII, and ``"``, ``\\``, ``/``, ``;``, ``%``,
becomes ``_``; control characters (CR, LF, ...) are dropped from both forms, so a robot name
can neither end the header line nor add a parameter of the client's choosing. Browsers and
curl (``-J``) take ``filename*`` and show the name as it was.
"""

from __future__ import annotations

import unicodedata
from typing import Final, Literal
from urllib.parse import quote

#: Longest file name sent [characters]; longer names are cut before the extension.
MAX_FILENAME_CHARS: Final = 120
#: Characters the ASCII fallback replaces with ``_`` (besides non-ASCII and controls).
_UNSAFE_ASCII: Final = frozenset('"\\/;%')


def _clean(name: str) -> str:
    """``name`` without control or format characters (Unicode categories C*), path
    separators turned into ``_``, cut to :data:`MAX_FILENAME_CHARS` keeping the extension."""
    kept = "".join(
        "_" if ch in "/\\" else ch for ch in name if not unicodedata.category(ch).startswith("C")
    ).strip()
    if len(kept) > MAX_FILENAME_CHARS:
        stem, dot, ext = kept.rpartition(".")
        ext = dot + ext if dot and len(ext) <= 8 else ""
        kept = (stem if ext else kept)[: MAX_FILENAME_CHARS - len(ext)] + ext
    return kept or "download"


def ascii_fallback(name: str) -> str:
    """The quoted ``filename`` of the header: printable ASCII only, no quote or backslash."""
    return "".join(
        ch if " " <= ch <= "~" and ch not in _UNSAFE_ASCII else "_" for ch in _clean(name)
    )


def content_disposition(
    filename: str, disposition: Literal["attachment", "inline"] = "attachment"
) -> str:
    """The header value for a download named ``filename`` (any Unicode; see the module).

    ``'q"; x="y.toml'`` gives ``attachment; filename="q__ x=_y.toml";
    filename*=UTF-8''q%22%3B%20x%3D%22y.toml``.
    """
    clean = _clean(filename)
    encoded = quote(clean, safe="!#$&+-.^_`|~")  # RFC 5987 attr-char, the rest %XX of UTF-8
    return f"{disposition}; filename=\"{ascii_fallback(clean)}\"; filename*=UTF-8''{encoded}"


def download_headers(
    filename: str, disposition: Literal["attachment", "inline"] = "attachment"
) -> dict[str, str]:
    """``{"Content-Disposition": ...}`` for a response's ``headers=``."""
    return {"Content-Disposition": content_disposition(filename, disposition)}
