"""The one lexer of the controller languages: numbers with their character spans, comments,
strings and brackets, parameterised per language by a :class:`Lexicon`.

Every reader of a program text, the writers' strict readers (``program.py``) and the
filter's dialects (``filter.py`` and their helpers) alike, scans with these functions, so a
number, a comment, a string or a bracket is recognised the same way on both sides. Offsets
are always offsets into the file's own text: :func:`blank` replaces comments and strings by
spaces of the same length (line ends kept), so a span found in the blanked code is the span
of the same characters in the file, and the filter can replace exactly one number.

Standard library only (the writers and the command line's ``--help`` import it cheaply).
"""

from __future__ import annotations

import math
import re
import sys
from collections.abc import Callable
from dataclasses import dataclass, field

#: A number as every controller language writes it: sign, digits, point, exponent.
NUMBER_PATTERN = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
NUMBER = re.compile(NUMBER_PATTERN)
#: Longest number text read [characters]: longer is no number a controller writes.
MAX_NUMBER_CHARS = 40
_LARGEST = sys.float_info.max
#: Any bracket: where an argument list nests.
BRACKETS = re.compile(r"[\[({\])}]")
_OPENING = "[({"
_CLOSING = "])}"
#: Characters a comment written by cablecal never holds, in any language: quotes (a string
#: opener), ``;`` (KRL's comment and every statement's end) and braces (KRL aggregates).
COMMENT_UNSAFE = "\"';{}"


@dataclass(frozen=True)
class Lexicon:
    """What one controller language's text is made of, for the lexer.

    Attributes
    ----------
    language : str
        The format's name (``rapid``, ``krl``, ``urscript``, ``fanuc-ls``).
    line_comments : tuple of str
        Markers that start a comment running to the end of the line (RAPID ``!``, KRL ``;``,
        URScript ``#``, Fanuc ``!`` and ``//`` in a ``/MN`` line's body).
    quotes : str
        Characters that open (and close) a string on one line.
    escape : str
        The character that escapes the next one inside a string (URScript ``\\``), or empty.
    case_insensitive : bool
        Whether keywords and names compare without case (RAPID, KRL, Fanuc).
    """

    language: str
    line_comments: tuple[str, ...]
    quotes: str
    escape: str = ""
    case_insensitive: bool = False
    _hidden: re.Pattern[str] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        parts = []
        for q in self.quotes:
            qe = re.escape(q)
            if self.escape:
                ee = re.escape(self.escape)
                parts.append(f"{qe}(?:[^{qe}{ee}\\n]|{ee}[\\s\\S]?)*{qe}?")
            else:
                parts.append(f"{qe}[^{qe}\\n]*{qe}?")
        parts += [re.escape(c) + r"[^\n]*" for c in self.line_comments]
        object.__setattr__(self, "_hidden", re.compile("|".join(parts)))

    @property
    def flags(self) -> re.RegexFlag:
        """``re.IGNORECASE`` for a case-insensitive language, else no flag."""
        return re.IGNORECASE if self.case_insensitive else re.NOFLAG

    def blank(self, text: str) -> str:
        """``text`` with comments and strings replaced by spaces, same length, line ends
        (``\\r``, ``\\n``) kept; whichever starts first wins (a comment marker inside a
        string is no comment, a quote inside a comment no string)."""
        return self._hidden.sub(_spaces, text)

    def comments(self, text: str) -> list[tuple[int, int]]:
        """Spans of the comments of ``text`` (marker included, line end excluded)."""
        quotes = self.quotes
        return [m.span() for m in self._hidden.finditer(text) if m.group()[0] not in quotes]

    def code_of(self, line: str) -> str:
        """One line without its comment (a comment marker inside a string is kept)."""
        for m in self._hidden.finditer(line):
            if m.group()[0] not in self.quotes:
                return line[: m.start()]
        return line

    def comment_of(self, line: str) -> str | None:
        """A whole-line comment's text, marker and surrounding blanks stripped; None when
        the line is not only a comment."""
        stripped = line.strip()
        for c in self.line_comments:
            if stripped.startswith(c):
                return stripped[len(c) :].strip()
        return None


def _spaces(m: re.Match[str]) -> str:
    g = m.group()
    if "\r" not in g and "\n" not in g:
        return " " * len(g)
    return re.sub(r"[^\r\n]", " ", g)


#: The languages' lexicons (ABB RAPID, KUKA KRL, UR URScript, Fanuc TP as ASCII).
RAPID = Lexicon("rapid", ("!",), '"', case_insensitive=True)
KRL = Lexicon("krl", (";",), '"', case_insensitive=True)
URSCRIPT = Lexicon("urscript", ("#",), "\"'", escape="\\")
FANUC = Lexicon("fanuc-ls", ("!", "//"), "\"'", case_insensitive=True)
LEXICONS: dict[str, Lexicon] = {lex.language: lex for lex in (RAPID, URSCRIPT, KRL, FANUC)}


def bounded(text: str, max_abs: float = _LARGEST) -> float | None:
    """The value of a number's text when it is at most :data:`MAX_NUMBER_CHARS` long and at
    most ``max_abs`` in magnitude (so finite); None otherwise (the caller names its file
    and line: :func:`shown`). Called for every number a program holds: kept minimal."""
    value = float(text) if len(text) <= MAX_NUMBER_CHARS else math.inf
    return value if abs(value) <= max_abs else None


def shown(text: str) -> str:
    """A number's text for a message, cut when long."""
    return text if len(text) <= 24 else f"{text[:12]}…({len(text)} characters)"


def number_value(text: str, fail: Callable[[str], Exception], max_abs: float = _LARGEST) -> float:
    """:func:`bounded`, raising ``fail(shown)`` (:func:`shown`) where it gives None."""
    value = bounded(text, max_abs)
    if value is None:
        raise fail(shown(text))
    return value


def is_number(text: str) -> bool:
    """Whether ``text`` is exactly one number (:data:`NUMBER_PATTERN`)."""
    return NUMBER.fullmatch(text) is not None


def skip_space(text: str, i: int) -> int:
    """The first offset at or after ``i`` that is no blank or line end."""
    while i < len(text) and text[i] in " \t\r\n":
        i += 1
    return i


def close_bracket(code: str, i: int) -> int:
    """Offset just after the bracket closing the one at ``code[i]`` (the same kind, nested
    ones counted), or -1 when it is not closed."""
    opening = code[i]
    closing = _CLOSING[_OPENING.index(opening)]
    depth = 0
    for k in range(i, len(code)):
        c = code[k]
        if c == opening:
            depth += 1
        elif c == closing:
            depth -= 1
            if depth == 0:
                return k + 1
    return -1


def split_top(code: str, start: int, end: int, sep: str = ",") -> list[tuple[int, int]]:
    """``code[start:end]`` split at ``sep`` at bracket depth 0 (``[]``, ``()``, ``{}``), as
    spans: a RAPID argument list, a URScript list or call."""
    if not BRACKETS.search(code, start, end):  # the common case: no nesting
        out: list[tuple[int, int]] = []
        last = start
        while (i := code.find(sep, last, end)) >= 0:
            out.append((last, i))
            last = i + 1
        out.append((last, end))
        return out
    out, depth, last = [], 0, start
    for i in range(start, end):
        c = code[i]
        if c in _OPENING:
            depth += 1
        elif c in _CLOSING:
            depth -= 1
        elif c == sep and depth == 0:
            out.append((last, i))
            last = i + 1
    out.append((last, end))
    return out


def find_top(code: str, char: str, start: int, end: int | None = None) -> int:
    """The first ``char`` at bracket depth ≤ 0 in ``code[start:end]``, or ``end`` (default:
    the end of the code) when there is none."""
    stop = len(code) if end is None else end
    j = code.find(char, start, stop)
    if j >= 0 and not BRACKETS.search(code, start, j):
        return j
    depth = 0
    for i in range(start, stop):
        c = code[i]
        if c in _OPENING:
            depth += 1
        elif c in _CLOSING:
            depth -= 1
        elif c == char and depth <= 0:
            return i
    return stop


def cuts_top(code: str, char: str, start: int, end: int) -> list[int]:
    """Offsets of every ``char`` at bracket depth 0 in ``code[start:end]``."""
    out, depth = [], 0
    for i in range(start, end):
        c = code[i]
        if c in _OPENING:
            depth += 1
        elif c in _CLOSING:
            depth -= 1
        elif c == char and depth == 0:
            out.append(i)
    return out


def clean_comment(text: str, max_len: int = 200) -> str:
    """A comment line safe in every language: printable ASCII without
    :data:`COMMENT_UNSAFE` (each becomes ``_``), cut to ``max_len``."""
    out = "".join(c if 32 <= ord(c) < 127 and c not in COMMENT_UNSAFE else "_" for c in text)
    return out[:max_len].rstrip()
