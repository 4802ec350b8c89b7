"""KRL text for the filter's KUKA dialect: comments, aggregates and ``.dat`` declarations.

What :mod:`calib.programs.krl.filter` needs of a KRL file, with every offset an offset into the
file's
own text (so the dialect can replace exactly one number):

* :func:`blank`: the text with ``;`` comments and ``"…"`` strings replaced by spaces (line
  ends kept; the shared lexer's, :mod:`calib.programs.lexer`), so nothing inside a comment
  or a string is ever taken for code;
* :func:`parse_aggregate`: a structure value ``{[TYPE:] KEY value, …}`` (nested
  aggregates allowed; values are numbers, ``'B101'``/``'H1F'`` bit literals, ``#ENUM``,
  ``TRUE``/``FALSE``, names or blanked strings);
* :func:`read_declarations`: the position, frame and ``FDAT`` data of a ``.dat`` (or
  ``$config.dat``): ``[DECL] [GLOBAL] [CONST] TYPE NAME={…}`` and arrays ``TYPE NAME[n]``
  with their element assignments ``NAME[i]={…}`` (also for arrays declared elsewhere, as
  ``TOOL_DATA[n]``/``BASE_DATA[n]`` in ``$config.dat``), and ``TOOL_TYPE[n]``/``BASE_TYPE[n]``.

KRL is case-insensitive: names are compared in upper case.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import PurePath

import numpy as np

from calib.kinematics import FloatArray
from calib.programs.lexer import KRL, NUMBER
from calib.programs.rotations import frame, zyx_deg_to_matrix
from calib.programs.sites import FilterInputError, Num, Source

_BITS = re.compile(r"'([BH])([0-9A-Fa-f]*)'")
_KEY = re.compile(r"[A-Za-z_$][\w$]*(?:\[\s*\])?")
#: The key of a flat aggregate's item and the blanks around it (a key with ``[`` is not flat).
_FLAT_KEY = re.compile(r"[ \t\r]*([A-Za-z_$][\w$]*(?:\[[ \t]*\])?)[ \t]*")
_SPACE = re.compile(r"[ \t\r\n]*")
_BLANKS = re.compile(r"[ \t]*")
_VALUE = re.compile(r"[^,}\r\n{]*")
_TYPE_PREFIX = re.compile(r"\s*([A-Za-z_$][\w$]*)\s*:(?!=)")
#: Position, axis and frame data types the filter reads.
POSITION_TYPES = ("E6POS", "POS", "FRAME")
AXIS_TYPES = ("E6AXIS", "AXIS")
DATA_TYPES = (*POSITION_TYPES, *AXIS_TYPES, "FDAT")
CARTESIAN_KEYS = ("X", "Y", "Z", "A", "B", "C")
_DECL = re.compile(
    r"^[ \t]*((?:(?:DECL|GLOBAL|CONST)[ \t]+)*)(" + "|".join(DATA_TYPES) + r")[ \t]+"
    r"([A-Za-z_$][\w$]*)[ \t]*(\[[^\]\r\n]*\])?[ \t]*(=[ \t]*(?=\{))?",
    re.IGNORECASE | re.MULTILINE,
)
_ELEMENT = re.compile(
    r"^[ \t]*([A-Za-z_$][\w$]*)[ \t]*\[([^\]\r\n]*)\][ \t]*=[ \t]*(?=\{)", re.MULTILINE
)
_TYPE_OF = re.compile(
    r"^[ \t]*(TOOL_TYPE|BASE_TYPE)[ \t]*\[[ \t]*(\d+)[ \t]*\][ \t]*=[ \t]*#(\w+)",
    re.IGNORECASE | re.MULTILINE,
)


#: ``text`` with ``;`` comments and ``"…"`` strings replaced by spaces, same length, line
#: ends kept (the shared lexer's; whichever starts first wins: a ``;`` inside a string is no
#: comment).
blank = KRL.blank


@dataclass(slots=True)
class Item:
    """One ``KEY value`` of an aggregate: the value's span, and what it is."""

    key: str  # upper case, e.g. "X", "S", "POINT2[]"
    start: int
    end: int
    text: str
    agg: Aggregate | None = None

    @property
    def num(self) -> float | None:
        """The value of a number or bit literal; None for anything else (read on demand:
        most components of a program's aggregates are never asked for)."""
        return None if self.agg is not None else literal_value(self.text)


@dataclass
class Aggregate:
    """A structure value ``{[TYPE:] KEY value, …}`` at ``[start, end)``."""

    start: int
    end: int
    type_name: str = ""  # upper case, "" when untyped
    items: dict[str, Item] = field(default_factory=dict)

    def num(self, source: Source, key: str) -> Num | None:
        """The number under ``key`` as a :class:`Num` (None when absent or not a number)."""
        it = self.items.get(key)
        value = None if it is None else it.num
        if it is None or value is None:
            return None
        return Num(source.name, it.start, it.end, it.text, value)


def literal_value(text: str) -> float | None:
    """A KRL number or bit literal (``'B110'``, ``'H1F'``) as a float; None otherwise."""
    m = NUMBER.fullmatch(text)
    if m:
        return float(text)
    b = _BITS.fullmatch(text)
    if b and b.group(2):
        return float(int(b.group(2), 2 if b.group(1).upper() == "B" else 16))
    return None


def _flat(code: str, j: int, agg: Aggregate) -> bool:
    """Fast path of :func:`parse_aggregate` for a well-formed aggregate on one line without
    nested aggregates (a position's): True when it filled ``agg``. Its items are the
    ``,``-separated parts up to the ``}``, each ``KEY value`` (blanks and a ``\r`` before
    the key, blanks around the value); anything else is left to the general path."""
    close = code.find("}", j)
    if close < 0 or code.find("{", j, close) >= 0 or code.find("\n", j, close) >= 0:
        return False
    items: dict[str, Item] = {}
    pos = j
    key_at = _FLAT_KEY.match
    for part in code[j:close].split(","):
        k = key_at(part)
        if k is None:
            return False
        key = k.group(1).upper()
        e = k.end()
        text = part[e:].rstrip(" \t")
        if "[" in key or "\r" in text or key in items:
            return False
        items[key] = Item(key, pos + e, pos + e + len(text), text)
        pos += len(part) + 1
    agg.items, agg.end = items, close + 1
    return True


def parse_aggregate(code: str, i: int, source: Source) -> Aggregate:
    """The aggregate whose ``{`` is at ``code[i]`` (``code`` blanked).

    Raises
    ------
    FilterInputError
        Naming the line of the first character that does not fit.
    """

    def fail(at: int, what: str) -> FilterInputError:
        got = repr(code[at]) if at < len(code) else "end of file"
        return FilterInputError(
            source.name, f"{what}, got {got} in an aggregate", source.line_of(at)
        )

    if i >= len(code) or code[i] != "{":
        raise fail(i, "expected '{'")
    agg = Aggregate(i, i)
    j = i + 1
    m = _TYPE_PREFIX.match(code, j)
    if m:
        agg.type_name = m.group(1).upper()
        j = m.end()
    flat = _flat(code, j, agg)
    if flat:
        return agg
    n = len(code)
    while True:
        j = _SPACE.match(code, j).end()  # type: ignore[union-attr]
        if j < n and code[j] == "}" and not agg.items:
            agg.end = j + 1
            return agg
        k = _KEY.match(code, j)
        if not k:
            raise fail(j, "expected a component name")
        key = k.group().upper()
        if "[" in key:
            key = key.replace(" ", "").replace("\t", "")
        j = _BLANKS.match(code, k.end()).end()  # type: ignore[union-attr]
        if j < n and code[j] == "{":
            sub = parse_aggregate(code, j, source)
            item = Item(key, sub.start, sub.end, code[sub.start : sub.end], agg=sub)
            j = sub.end
        else:
            v = _VALUE.match(code, j)
            assert v is not None
            text = v.group().rstrip(" \t")
            item = Item(key, j, j + len(text), text)
            j = v.end()
        if key in agg.items:
            raise FilterInputError(
                source.name, f"component {key} given twice", source.line_of(item.start)
            )
        agg.items[key] = item
        j = _BLANKS.match(code, j).end()  # type: ignore[union-attr]
        if j < n and code[j] == ",":
            j += 1
            continue
        if j < n and code[j] == "}":
            agg.end = j + 1
            return agg
        raise fail(j, "expected ',' or '}'")


@dataclass
class Decl:
    """A declaration (or array) of position, axis, frame or ``FDAT`` data in a ``.dat``.

    ``value`` for a single value, ``elements`` (index tuple → aggregate) for an array.
    ``kind`` is the declared type (``E6POS`` …); for an array assigned without a
    declaration in the given files (``TOOL_DATA`` in ``$config.dat``) it is ``""``.
    """

    kind: str
    name: str
    file: str
    line: int
    is_global: bool
    dims: tuple[int, ...] = ()
    value: Aggregate | None = None
    elements: dict[tuple[int, ...], Aggregate] = field(default_factory=dict)
    element_lines: dict[tuple[int, ...], int] = field(default_factory=dict)


@dataclass
class DataFile:
    """What one ``.dat`` declares: ``decls`` by upper-case name, and the tool and base
    types of ``$config.dat`` (``TOOL_TYPE[n]``/``BASE_TYPE[n]`` → ``#NONE``, ``#TCP`` …)."""

    source: Source
    code: str
    decls: dict[str, Decl] = field(default_factory=dict)
    tool_type: dict[int, str] = field(default_factory=dict)
    base_type: dict[int, str] = field(default_factory=dict)


def _index(text: str, source: Source, line: int) -> tuple[int, ...] | None:
    """``"1, 2"`` → ``(1, 2)``; None for a non-literal index (a variable)."""
    parts = [p.strip() for p in text.split(",")]
    if not all(re.fullmatch(r"\d+", p) for p in parts):
        return None
    out = tuple(int(p) for p in parts)
    if any(v < 1 for v in out):
        raise FilterInputError(source.name, f"array index [{text}] below 1", line)
    return out


def read_declarations(source: Source) -> DataFile:
    """The data of a ``.dat`` (see the module docstring).

    Raises
    ------
    FilterInputError
        A malformed aggregate or array index, or a name declared twice, naming the line.
    """
    code = blank(source.text)
    out = DataFile(source, code)
    config = PurePath(source.name).name.lower() == "$config.dat"  # every name in it is global
    for m in _DECL.finditer(code):
        line = source.line_of(m.start())
        kind, name = m.group(2).upper(), m.group(3)
        dims: tuple[int, ...] = ()
        if m.group(4):
            dims = _index(m.group(4)[1:-1], source, line) or (-1,)
        value = parse_aggregate(code, m.end(), source) if m.group(5) else None
        key = name.upper()
        if key in out.decls:
            raise FilterInputError(
                source.name, f"{name} declared twice (also line {out.decls[key].line})", line
            )
        is_global = "GLOBAL" in m.group(1).upper() or config
        out.decls[key] = Decl(kind, name, source.name, line, is_global, dims, value)
    for m in _ELEMENT.finditer(code):
        line = source.line_of(m.start())
        key = m.group(1).upper()
        idx = _index(m.group(2), source, line)
        if idx is None:
            continue
        decl = out.decls.get(key)
        if decl is None:
            decl = out.decls[key] = Decl("", m.group(1), source.name, line, True, ())
        if not decl.dims and decl.kind:
            raise FilterInputError(source.name, f"{m.group(1)} is not an array", line)
        if idx in decl.elements:
            raise FilterInputError(
                source.name,
                f"{m.group(1)}[{m.group(2)}] assigned twice (also line {decl.element_lines[idx]})",
                line,
            )
        decl.elements[idx] = parse_aggregate(code, m.end(), source)
        decl.element_lines[idx] = line
    for m in _TYPE_OF.finditer(code):
        table = out.tool_type if m.group(1).upper() == "TOOL_TYPE" else out.base_type
        table[int(m.group(2))] = m.group(3).upper()
    return out


def index_text(index: tuple[int, ...]) -> str:
    """``(1, 2)`` → ``"[1,2]"``, ``()`` → ``""``."""
    return "[" + ",".join(str(i) for i in index) + "]" if index else ""


@dataclass
class KrlFrame:
    """The tool or base in force: its name, frame (None: unknown) and why unknown."""

    name: str
    value: FloatArray | None
    problem: str

    def same(self, other: KrlFrame) -> bool:
        if self.value is None or other.value is None:
            return self.value is None and other.value is None and self.problem == other.problem
        return self.name == other.name and bool(np.allclose(self.value, other.value))


def unknown_frame(why: str) -> KrlFrame:
    return KrlFrame("?", None, why)


def frame_of(agg: Aggregate, what: str, src: Source) -> tuple[FloatArray | None, str]:
    vals = [agg.items.get(k) for k in CARTESIAN_KEYS]
    if any(v is None or v.num is None for v in vals):
        return (
            None,
            f"{what} is not a full frame {{X,Y,Z,A,B,C}} ({src.name}:{src.line_of(agg.start)})",
        )
    x, y, z, a, b, c = (float(v.num or 0.0) for v in vals if v is not None)
    return frame(np.array([x, y, z]), zyx_deg_to_matrix(a, b, c)), ""


@dataclass
class Program:
    """The files of one dialect run: ``.dat`` data and the ``.src`` sources."""

    data: dict[str, DataFile] = field(default_factory=dict)  # by file name
    srcs: list[Source] = field(default_factory=list)
    _tables: dict[tuple[str, int], KrlFrame] = field(default_factory=dict)
    _own: dict[str, DataFile | None] = field(default_factory=dict)
    _codes: dict[str, str] = field(default_factory=dict)

    def code_of(self, src: Source) -> str:
        """:func:`blank` of a ``.src``'s text (once per file)."""
        if src.name not in self._codes:
            self._codes[src.name] = blank(src.text)
        return self._codes[src.name]

    def own_dat(self, src_name: str) -> DataFile | None:
        """The ``.dat`` of the same name as the ``.src`` (case-insensitive)."""
        if src_name not in self._own:
            self._own[src_name] = self._own_dat(src_name)
        return self._own[src_name]

    def _own_dat(self, src_name: str) -> DataFile | None:
        stem = PurePath(src_name).with_suffix("").as_posix().lower()
        same = (
            df
            for name, df in self.data.items()
            if PurePath(name).with_suffix("").as_posix().lower() == stem
        )
        return next(same, None)

    def lookup(self, name: str, src_name: str | None) -> Decl | None:
        """``name`` in the ``.src``'s own ``.dat`` first, then the GLOBAL data of the others
        (all of ``$config.dat``'s, and arrays assigned without a declaration); None when
        absent or found in several. Without ``src_name``: any file's."""
        key = name.upper()
        own = self.own_dat(src_name) if src_name else None
        if own is not None and key in own.decls:
            return own.decls[key]
        found = [
            df.decls[key]
            for df in self.data.values()
            if df is not own and key in df.decls and (df.decls[key].is_global or src_name is None)
        ]
        return found[0] if len(found) == 1 else None

    def table(self, which: str, n: int) -> KrlFrame:
        """``TOOL_DATA[n]`` or ``BASE_DATA[n]`` (0: the identity)."""
        key = (which, n)
        if key not in self._tables:
            self._tables[key] = self._table(which, n)
        return self._tables[key]

    def _table(self, which: str, n: int) -> KrlFrame:
        label = f"{which}[{n}]"
        if n == 0:
            return KrlFrame(label, np.eye(4), "")
        types = [
            (df.tool_type if which == "TOOL_DATA" else df.base_type).get(n)
            for df in self.data.values()
        ]
        external = {"TOOL_DATA": "#BASE", "BASE_DATA": "#TCP"}[which]
        if external in types:
            kind = which.split("_")[0]
            return unknown_frame(
                f"{label}: external TCP ({kind}_TYPE[{n}]={external}) not supported"
            )
        decl = self.lookup(which, None)
        agg = decl.elements.get((n,)) if decl is not None else None
        if agg is None:
            return unknown_frame(f"{label} is not in the given files (give $config.dat)")
        value, why = frame_of(agg, label, self.data[decl.file].source)  # type: ignore[union-attr]
        return KrlFrame(label, value, why)
