"""The text rules of request bodies: the longest names, anchors, reasons and notes, and the
one printable-text rule (no control characters, valid Unicode) that every text field uses."""

from __future__ import annotations

import itertools
import re
import unicodedata
from typing import Annotated, Any

from pydantic import AfterValidator, BeforeValidator, Field, StringConstraints

#: Longest campaign name, anchor id, exclusion reason and campaign notes [characters].
MAX_NAME_CHARS = 200
MAX_ANCHOR_CHARS = 32
MAX_REASON_CHARS = 500
MAX_NOTES_CHARS = 10_000


def no_surrogates(value: Any, where: str = "body") -> None:
    """Raise ValueError if any string in ``value`` (recursively) cannot be UTF-8 (an unpaired
    surrogate such as ``"\\ud800"``, which JSON can spell but SQLite cannot store)."""
    if isinstance(value, str):
        try:
            value.encode("utf-8")
        except UnicodeEncodeError as exc:
            raise ValueError(f"{where}: not valid Unicode text ({exc.reason})") from None
    elif isinstance(value, dict):
        for k, v in value.items():
            no_surrogates(k, where)
            no_surrogates(v, f"{where}.{k}")
    elif isinstance(value, list):
        for i, v in enumerate(value):
            no_surrogates(v, f"{where}[{i}]")


def _not_blank(value: str) -> str:
    if not value:
        raise ValueError("must not be empty or blank")
    return value


def _format_characters() -> list[int]:
    """Code points of Unicode's format characters (category Cf: bidi controls such as U+202E
    and U+2066, zero-width characters such as U+200B, the BOM U+FEFF, ...; all below U+20000
    or in the tag block U+E0000..U+E007F), the line and paragraph separators U+2028/U+2029,
    and the noncharacters U+FFFE/U+FFFF: invisible, or acting on how the text around them is
    shown, read or split into lines."""
    scan = itertools.chain(range(0x20000), range(0xE0000, 0xE0080))
    return [c for c in scan if unicodedata.category(chr(c)) == "Cf"] + [
        0x2028,
        0x2029,
        0xFFFE,
        0xFFFF,
    ]


def _char_class(codes: list[int]) -> str:
    """A regular-expression class body of ``codes`` as ranges; ``\\uXXXX`` escapes in the
    BMP, the characters themselves above it (Python's re and ECMA-262 with the u flag read
    both alike)."""

    def one(c: int) -> str:
        return f"\\u{c:04x}" if c <= 0xFFFF else chr(c)

    out, codes = [], sorted(set(codes))
    start = prev = codes[0]
    for c in [*codes[1:], -1]:
        if c == prev + 1:
            prev = c
            continue
        out.append(one(start) if start == prev else f"{one(start)}-{one(prev)}")
        start = prev = c
    return "".join(out)


_FORMAT = _char_class(_format_characters())
#: C0 and C1 control characters (and DEL), and the format characters above: never in a
#: name, an anchor, a reason or notes (ESC, BEL, CR, ... would act on a terminal or break a
#: line of an exported file; a bidi override or a zero-width space hides what a text says).
_CONTROL = re.compile(f"[\x00-\x1f\x7f-\x9f{_FORMAT}]")
#: The same, except the line feed and the tab that notes may hold.
_CONTROL_BUT_LINES = re.compile(f"[\x00-\x08\x0b-\x1f\x7f-\x9f{_FORMAT}]")
#: The schema's patterns of the same rules (ECMA-262 and Python read them alike).
_PRINTABLE = f"[^\\x00-\\x1f\\x7f-\\x9f{_FORMAT}]"
_PRINTABLE_NOTES = f"[^\\x00-\\x08\\x0b-\\x1f\\x7f-\\x9f{_FORMAT}]"


_KINDS = {
    "Cc": "control character",
    "Cf": "format character",
    "Zl": "line separator",
    "Zp": "paragraph separator",
}


def not_printable(text: str, pattern: re.Pattern[str] = _CONTROL) -> str | None:
    """Why ``text`` is not printable text (its first control or format character and its
    position), or None; also the rule of a CSV import's ``anchor`` and ``group`` cells."""
    found = pattern.search(text)
    if found is None:
        return None
    char = found.group()
    kind = _KINDS.get(unicodedata.category(char), "noncharacter")
    return f"{kind} U+{ord(char):04X} at position {found.start()}"


#: Longest uploaded file name [characters].
MAX_FILE_NAME_CHARS = 128
#: A portable file name: ASCII letters, digits and ``._-+()`` and spaces, starting with a
#: letter, a digit or ``_``, not ending in a dot or a space (Windows drops those). So no
#: directory, drive (``C:``), control, format or non-ASCII character, and the same bytes
#: on every file system and in every zip tool.
_PORTABLE_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.+() -]*(?<![. ])")
#: Windows' reserved device names: no file may be called so, whatever its extension.
_RESERVED = frozenset(
    ["CON", "PRN", "AUX", "NUL", "CONIN$", "CONOUT$"]
    + [f"{d}{n}" for d in ("COM", "LPT") for n in "123456789\u00b9\u00b2\u00b3"]
)


def not_portable_file_name(name: str, taken: list[str] | tuple[str, ...] = ()) -> str | None:
    """Why ``name`` is not a portable file name (see :data:`_PORTABLE_NAME`), or None: also a
    Windows device name (``CON.mod``) or a name that differs from one in ``taken`` only in
    case (``A.mod`` beside ``a.mod``: one overwrites the other on Windows and macOS)."""
    if not 1 <= len(name) <= MAX_FILE_NAME_CHARS or not _PORTABLE_NAME.fullmatch(name):
        return (
            f"file name {name!r} must be a plain name, portable: 1..{MAX_FILE_NAME_CHARS} "
            "ASCII letters, digits, spaces and ._-+(), starting with a letter, digit or _, "
            "not ending in . or a space (no directory or drive)"
        )
    if name.split(".", 1)[0].rstrip(" ").upper() in _RESERVED:
        return f"file name {name!r} is a reserved device name on Windows"
    for other in taken:
        if other.casefold() == name.casefold():
            same = "given twice" if other == name else f"differs from {other!r} only in case"
            return f"file name {name!r} {same}"
    return None


def _printable(pattern: re.Pattern[str], allowed: str) -> Any:
    """A validator (run on the value as sent, before stripping) refusing what ``pattern``
    finds, naming the character and its position."""

    def check(value: Any) -> Any:
        if isinstance(value, str) and (why := not_printable(value, pattern)):
            raise ValueError(f"{why}: {allowed}")
        return value

    return BeforeValidator(check)


_NO_CONTROL = _printable(_CONTROL, "only printable text is allowed")
_NO_CONTROL_BUT_LINES = _printable(
    _CONTROL_BUT_LINES, "only printable text, line feeds and tabs are allowed"
)
_Stripped = StringConstraints(strip_whitespace=True)
#: The "not blank" and "printable" rules as the schema states them (at least one non-space
#: character, no control character); the server's checks are :func:`_not_blank` after
#: stripping and :data:`_NO_CONTROL` before it, with their own messages.
NOT_BLANK_SCHEMA: dict[str, Any] = {
    "minLength": 1,
    "pattern": f"^{_PRINTABLE}*[^\\s\\x00-\\x1f\\x7f-\\x9f{_FORMAT}]{_PRINTABLE}*$",
}
Name = Annotated[
    str,
    _Stripped,
    Field(max_length=MAX_NAME_CHARS, json_schema_extra=NOT_BLANK_SCHEMA),
    AfterValidator(_not_blank),
    _NO_CONTROL,
]
Anchor = Annotated[
    str,
    _Stripped,
    Field(max_length=MAX_ANCHOR_CHARS, json_schema_extra=NOT_BLANK_SCHEMA),
    AfterValidator(_not_blank),
    _NO_CONTROL,
]
Notes = Annotated[
    str,
    _Stripped,
    Field(max_length=MAX_NOTES_CHARS, pattern=f"^{_PRINTABLE_NOTES}*$"),
    _NO_CONTROL_BUT_LINES,
]
Reason = Annotated[
    str, _Stripped, Field(max_length=MAX_REASON_CHARS, pattern=f"^{_PRINTABLE}*$"), _NO_CONTROL
]
