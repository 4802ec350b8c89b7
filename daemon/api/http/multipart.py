"""A ``multipart/form-data`` body read as it streams, with its limits applied while reading.

The bytes go through python-multipart's streaming :class:`~python_multipart.MultipartParser`
(a state machine: no recursion, no regular expression over the body) as each chunk arrives,
and every bound is checked on the way, so a hostile body costs at most its limits:

- **parts**: each part's name is checked when its headers end; a name the route does not
  read, or one part too many of a name, is refused before the part's data is read;
- **headers**: at most :data:`MAX_PART_HEADERS` header lines of a part, at most
  :data:`MAX_PART_HEADER_BYTES` bytes for all of them, and at most :data:`MAX_PARAMS`
  parameters in its ``Content-Disposition`` (a file part has two: ``name`` and
  ``filename``); RFC 2231 extended parameters (``filename*``), which RFC 7578 forbids in
  form data, are ignored;
- **body**: the part data together at most the route's byte limit (the request guard
  bounds the whole body as well);
- **end**: a body that ends without its closing boundary is refused (truncated).

A ``Content-Transfer-Encoding`` other than the identity ones (RFC 7578 deprecates it; no
browser or HTTP client sends it) is refused rather than decoded.
"""

from __future__ import annotations

import logging
from collections.abc import AsyncIterator, Mapping
from dataclasses import dataclass, field
from typing import Final

from fastapi.exceptions import RequestValidationError
from python_multipart.exceptions import MultipartParseError
from python_multipart.multipart import MultipartParser, MultipartState, parse_options_header
from starlette.exceptions import HTTPException

from daemon.api.errors import unprocessable

#: Most header lines in one part (a file part has one or two).
MAX_PART_HEADERS: Final = 8
#: Most bytes of all header lines of one part, names and values.
MAX_PART_HEADER_BYTES: Final = 2048
#: Most parameters of a part's ``Content-Disposition`` (``name``, ``filename``, ...).
MAX_PARAMS: Final = 8
#: Longest ``Content-Type`` of the request [characters] (type, boundary and parameters).
MAX_CONTENT_TYPE_CHARS: Final = 1024
_IDENTITY_ENCODINGS = frozenset({"", "7bit", "8bit", "binary"})

# The parser logs a warning for each malformed body before it raises; the refusal is the
# API's answer (and its access log), so a flood of hostile bodies writes no second log line.
logging.getLogger("python_multipart").setLevel(logging.ERROR)


@dataclass
class FormPart:
    """One part of the body: its ``name``, its ``filename`` (None when absent), its bytes
    as sent, and its index among all parts (0-based)."""

    index: int
    name: str
    filename: str | None
    data: bytearray = field(default_factory=bytearray)


def _refuse(where: str, message: str) -> RequestValidationError:
    """A 422 naming ``where`` (``body`` or a part name) and what is wrong."""
    return unprocessable(("body",) if where == "body" else ("body", where), message)


def _boundary(content_type: str) -> bytes:
    """The boundary of a ``multipart/form-data`` ``Content-Type``, or a 422."""
    if len(content_type) > MAX_CONTENT_TYPE_CHARS:
        raise _refuse("body", f"Content-Type: longer than {MAX_CONTENT_TYPE_CHARS} characters")
    if content_type.count(";") > MAX_PARAMS:
        raise _refuse("body", f"Content-Type: more than {MAX_PARAMS} parameters")
    kind, params = parse_options_header(content_type)
    boundary = params.get(b"boundary", b"")
    if kind != b"multipart/form-data" or not boundary:
        raise _refuse("body", "body: expected multipart/form-data (with a boundary)")
    if len(boundary) > 70 or not boundary.isascii():
        raise _refuse("body", "Content-Type: boundary must be 1..70 ASCII characters (RFC 2046)")
    return boundary


class FormReader:
    """Feed a ``multipart/form-data`` body chunk by chunk; :meth:`finish` returns its parts.

    Parameters
    ----------
    content_type : str
        The request's ``Content-Type`` (carries the boundary).
    fields : mapping of str to int
        The part names the route reads, each with the most parts of that name.
    max_data_bytes : int
        The most bytes of part data, all parts together.

    Every refusal is an HTTP error raised from :meth:`feed` or :meth:`finish`: 422 naming the
    part (its name and index) or ``body``, 413 for data over ``max_data_bytes``.
    """

    def __init__(self, content_type: str, fields: Mapping[str, int], max_data_bytes: int) -> None:
        self.fields = dict(fields)
        self.max_data_bytes = max_data_bytes
        self.parts: list[FormPart] = []
        self._data_bytes = 0
        self._current: FormPart | None = None
        self._headers: list[tuple[bytearray, bytearray]] = []
        self._header_bytes = 0
        self._ended = False
        self._parser = MultipartParser(
            _boundary(content_type),
            {
                "on_part_begin": self._part_begin,
                "on_header_field": self._header_field,
                "on_header_value": self._header_value,
                "on_headers_finished": self._headers_finished,
                "on_part_data": self._part_data,
                "on_part_end": self._part_end,
                "on_end": self._end,
            },
            max_header_count=MAX_PART_HEADERS,
            max_header_size=MAX_PART_HEADER_BYTES,
        )

    # ---------------------------------------------------------------- parser callbacks
    def _where(self) -> str:
        return f"part {len(self.parts)}"

    def _part_begin(self) -> None:
        if len(self.parts) >= sum(self.fields.values()):
            raise _refuse(
                "body", f"body: more than {sum(self.fields.values())} parts ({self._names()})"
            )
        self._headers = []
        self._header_bytes = 0
        self._current = None

    def _count_header(self, n: int) -> None:
        self._header_bytes += n
        if self._header_bytes > MAX_PART_HEADER_BYTES:
            raise _refuse(
                "body", f"{self._where()}: headers longer than {MAX_PART_HEADER_BYTES} bytes"
            )

    def _header_field(self, data: bytes, start: int, end: int) -> None:
        self._count_header(end - start)
        if not self._headers or self._headers[-1][1]:
            self._headers.append((bytearray(), bytearray()))
        self._headers[-1][0].extend(data[start:end])

    def _header_value(self, data: bytes, start: int, end: int) -> None:
        self._count_header(end - start)
        if not self._headers:  # pragma: no cover (the parser reads a field first)
            self._headers.append((bytearray(), bytearray()))
        self._headers[-1][1].extend(data[start:end])

    def _headers_finished(self) -> None:
        where = self._where()
        headers: dict[str, str] = {}
        for raw_name, raw_value in self._headers:
            name = raw_name.decode("latin-1").strip().lower()
            if name in headers:
                raise _refuse("body", f"{where}: header {name} given twice")
            headers[name] = raw_value.decode("latin-1").strip()
        encoding = headers.get("content-transfer-encoding", "").lower()
        if encoding not in _IDENTITY_ENCODINGS:
            raise _refuse(
                "body",
                f"{where}: Content-Transfer-Encoding {encoding!r} is not read; send the "
                "bytes as they are",
            )
        disposition = headers.get("content-disposition")
        if disposition is None:
            raise _refuse("body", f"{where}: no Content-Disposition header")
        if disposition.count(";") > MAX_PARAMS:
            raise _refuse("body", f"{where}: Content-Disposition has over {MAX_PARAMS} parameters")
        kind, params = parse_options_header(disposition)
        if kind != b"form-data":
            raise _refuse("body", f"{where}: Content-Disposition must be form-data")
        part_name = params.get(b"name")
        if part_name is None:
            raise _refuse("body", f"{where}: its Content-Disposition has no name ({self._names()})")
        name = _text(part_name)
        if name not in self.fields:
            raise _refuse(name, f"{where}: unknown part {name!r} ({self._names()})")
        if sum(p.name == name for p in self.parts) >= self.fields[name]:
            raise _refuse(name, f"{name}: at most {self.fields[name]} parts of this name")
        filename = params.get(b"filename")
        self._current = FormPart(
            len(self.parts), name, None if filename is None else _text(filename)
        )

    def _part_data(self, data: bytes, start: int, end: int) -> None:
        self._data_bytes += end - start
        if self._data_bytes > self.max_data_bytes:
            raise HTTPException(413, f"body: larger than the limit of {self.max_data_bytes} bytes")
        if self._current is None:  # pragma: no cover (headers always finish first)
            raise _refuse("body", f"{self._where()}: data before its headers")
        self._current.data.extend(data[start:end])

    def _part_end(self) -> None:
        if self._current is None:  # a part whose headers never finished
            raise _refuse("body", f"{self._where()}: ends inside its headers")
        self.parts.append(self._current)
        self._current = None

    def _end(self) -> None:
        self._ended = True

    def _names(self) -> str:
        return "expected " + ", ".join(self.fields)

    # ---------------------------------------------------------------- feeding
    def feed(self, chunk: bytes) -> None:
        """Parse the next chunk of the body."""
        if self._ended:
            return  # the epilogue after the closing boundary is ignored (RFC 2046)
        try:
            self._parser.write(chunk)
        except MultipartParseError as exc:
            raise _refuse("body", f"body: not a valid multipart body: {exc}") from None

    def finish(self) -> list[FormPart]:
        """The parts, once the whole body was fed; a body without its closing boundary is a
        422."""
        if not self._ended or self._parser.state != MultipartState.END:
            raise _refuse(
                "body", "body: truncated: the multipart body ends without its closing boundary"
            )
        return self.parts


def _text(raw: bytes) -> str:
    """A header parameter as text: UTF-8 (what browsers and HTTP clients send), else latin-1."""
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError:
        return raw.decode("latin-1")


async def read_form(
    chunks: AsyncIterator[bytes],
    content_type: str,
    fields: Mapping[str, int],
    max_data_bytes: int,
) -> list[FormPart]:
    """The parts of a streamed ``multipart/form-data`` body, read under the limits of
    :class:`FormReader` as each chunk arrives (see the module docstring)."""
    reader = FormReader(content_type, fields, max_data_bytes)
    async for chunk in chunks:
        reader.feed(chunk)
    return reader.finish()
