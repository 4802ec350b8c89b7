"""The text rules of request bodies: the longest names, anchors, reasons and notes, and the
one printable-text rule (no control characters, valid Unicode) that every text field uses."""

from __future__ import annotations

import re
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


#: C0 and C1 control characters (and DEL): never in a name, an anchor, a reason or notes
#: (ESC, BEL, CR, ... would act on a terminal or break a line of an exported file).
_CONTROL = re.compile("[\x00-\x1f\x7f-\x9f]")
#: The same, except the line feed and the tab that notes may hold.
_CONTROL_BUT_LINES = re.compile("[\x00-\x08\x0b-\x1f\x7f-\x9f]")
#: The schema's patterns of the same rules (ECMA-262 and Python read them alike).
_PRINTABLE = "[^\\x00-\\x1f\\x7f-\\x9f]"
_PRINTABLE_NOTES = "[^\\x00-\\x08\\x0b-\\x1f\\x7f-\\x9f]"


def not_printable(text: str, pattern: re.Pattern[str] = _CONTROL) -> str | None:
    """Why ``text`` is not printable text (its first control character and position), or
    None; also the rule of a CSV import's ``anchor`` and ``group`` cells."""
    found = pattern.search(text)
    if found is None:
        return None
    return f"control character U+{ord(found.group()):04X} at position {found.start()}"


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
    "pattern": f"^{_PRINTABLE}*[^\\s\\x00-\\x1f\\x7f-\\x9f]{_PRINTABLE}*$",
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
