"""A RAPID module's structure and declarations, as RAPID scopes them.

Structure
    A module is ``MODULE name`` … ``ENDMODULE`` (after an optional ``%%%`` header), holding
    data declarations and routines: ``PROC name(…)`` … ``ENDPROC``, ``FUNC type name(…)`` …
    ``ENDFUNC``, ``TRAP name`` … ``ENDTRAP`` (each optionally ``LOCAL``). A file that does not
    end properly (no ``ENDMODULE``, a routine without its end, text after ``ENDMODULE``, a
    second ``MODULE``) is refused with the file and line: it is a module cut short (a copy
    that stopped mid-way) or two modules run together, and a filtered copy of it would be as
    broken as the original.

Declarations
    ``CONST``, ``PERS`` or ``VAR`` (``PERS`` and ``VAR`` optionally ``TASK`` or ``LOCAL``) of
    ``robtarget``, ``jointtarget``, ``tooldata`` and ``wobjdata``, single or arrays
    (``{n}``, ``{n,m}``). A declaration inside a routine is that routine's own: the same
    name in two routines is two data (RAPID's routine scope). A ``LOCAL`` module declaration
    is seen only by its own module.

Lookup (:func:`lookup`)
    As RAPID resolves a name used in a routine: the routine's own data, then its module's,
    then the global (not ``LOCAL``) data of the other modules given. RAPID is
    case-insensitive.
"""

from __future__ import annotations

import bisect
import re
from dataclasses import dataclass, field
from typing import Any

from calib.kinematics import FloatArray
from calib.programs.rapid.syntax import (
    ROBTARGET,
    Node,
    blank,
    is_jointtarget,
    is_robtarget,
    parse_literal,
    skip_space,
)
from calib.programs.sites import FilterInputError, Source

DECL = re.compile(
    r"\b(?:(LOCAL|TASK)\s+)?(?:CONST|PERS|VAR)\s+(robtarget|jointtarget|tooldata|wobjdata)"
    r"\s+([A-Za-z]\w*)\s*(\{[^}]*\})?\s*(:=)?",
    re.IGNORECASE,
)
HEADER = re.compile(r"^\s*(?:%%%[\s\S]*?%%%\s*)?(?=MODULE\s+\w+)", re.IGNORECASE)
_STRUCTURE = re.compile(
    r"\b(?:(ENDPROC|ENDFUNC|ENDTRAP|ENDMODULE)\b"
    r"|(?:LOCAL\s+)?(PROC|TRAP)\s+([A-Za-z]\w*)"
    r"|(?:LOCAL\s+)?(FUNC)\s+[A-Za-z]\w*\s+([A-Za-z]\w*)"
    r"|(MODULE)\s+(\w+))",
    re.IGNORECASE,
)


@dataclass
class Routine:
    """A routine: its name as written, kind (``proc``, ``func``, ``trap``), and the character
    span of its text from the keyword to the end keyword (exclusive)."""

    name: str
    kind: str
    start: int
    end: int
    line: int


@dataclass
class Decl:
    """A declaration: ``kind`` (lower case), ``name`` as written, its ``scope`` (the name of its
    routine as written, empty at module level), whether it is ``LOCAL``, its literal value
    (None without one), array ``dims`` and, per index, the element literals; ``fast`` holds a
    plain single robtarget read by :data:`ROBTARGET` (no node tree); ``targets`` the
    dialect's target sites by index (filled by the dialect)."""

    kind: str
    name: str
    file: str
    line: int
    value: Node | None
    dims: tuple[int, ...]
    scope: str = ""
    local: bool = False
    elements: dict[tuple[int, ...], Node] = field(default_factory=dict)
    fast: re.Match[str] | None = None
    targets: dict[tuple[int, ...], Any] = field(default_factory=dict)

    @property
    def where(self) -> str:
        return f"{self.file}:{self.line}"


@dataclass
class Module:
    """One file: its text blanked (comments and strings as spaces), routines in order, and
    declarations by ``(lower-case scope, lower-case name)``; memo tables for the dialect."""

    source: Source
    code: str
    routines: list[Routine] = field(default_factory=list)
    starts: list[int] = field(default_factory=list)  # of the routines, for routine_at
    decls: dict[tuple[str, str], Decl] = field(default_factory=dict)
    frames: dict[tuple[str, str, str], tuple[FloatArray | None, str]] = field(default_factory=dict)
    lookups: dict[tuple[str, str, tuple[str, ...]], tuple[Decl | None, str]] = field(
        default_factory=dict
    )

    def routine_at(self, offset: int) -> Routine | None:
        """The routine whose text holds ``offset``, None at module level."""
        if len(self.starts) != len(self.routines):
            self.starts = [r.start for r in self.routines]
        k = bisect.bisect_right(self.starts, offset) - 1
        if k >= 0 and offset < self.routines[k].end:
            return self.routines[k]
        return None


def index_text(index: tuple[int, ...]) -> str:
    """``(2, 3)`` → ``{2,3}``; ``()`` → ``""``."""
    return "{" + ",".join(str(i) for i in index) + "}" if index else ""


def _dims(text: str | None) -> tuple[int, ...]:
    if not text:
        return ()
    try:
        return tuple(int(v) for v in text.strip("{} \t").split(","))
    except ValueError:
        return (-1,)  # a dimension given by a constant name: elements still read by shape


def _elements(
    node: Node, depth: int, index: tuple[int, ...], out: dict[tuple[int, ...], Node]
) -> None:
    if depth == 0:
        out[index] = node
        return
    for k, item in enumerate(node.items or []):
        _elements(item, depth - 1, (*index, k + 1), out)


def read_module(src: Source) -> Module:
    """The structure and declarations of one file.

    Raises
    ------
    FilterInputError
        Not a module, a module that does not end properly, a declaration whose literal does
        not fit its type, a name declared twice in one scope, a number out of range.
    """
    code = blank(src.text)
    head = HEADER.match(code.lstrip("\ufeff"))
    if head is None:
        raise FilterInputError(src.name, "not a RAPID module (no MODULE statement)", 1)
    mod = Module(src, code)
    _read_structure(mod)
    _read_decls(mod)
    return mod


def _read_structure(mod: Module) -> None:
    src, code = mod.source, mod.code
    in_module = False
    done = -1  # the end of ENDMODULE once read
    open_routine: tuple[str, str, int] | None = None  # kind, name, start
    for m in _STRUCTURE.finditer(code):
        line = src.line_of(m.start())
        if done >= 0:
            break
        end_word, module_word = m.group(1), m.group(6)
        if module_word:
            if in_module:
                raise FilterInputError(
                    src.name, "MODULE inside a module: the ENDMODULE before it is missing", line
                )
            in_module = True
            continue
        if not in_module:
            raise FilterInputError(src.name, f"{m.group().split()[0]} before MODULE", line)
        if end_word:
            word = end_word.upper()
            if word == "ENDMODULE":
                if open_routine is not None:
                    kind, name, start = open_routine
                    raise FilterInputError(
                        src.name,
                        f"ENDMODULE inside {kind.upper()} {name} (line {src.line_of(start)}): "
                        f"END{kind.upper()} is missing",
                        line,
                    )
                done = m.end()
                continue
            if open_routine is None or word != "END" + open_routine[0].upper():
                raise FilterInputError(src.name, f"{word} without its routine", line)
            kind, name, start = open_routine
            mod.routines.append(Routine(name, kind, start, m.start(), src.line_of(start)))
            open_routine = None
            continue
        kind = (m.group(2) or m.group(4)).lower()
        name = m.group(3) or m.group(5)
        if open_routine is not None:
            okind, oname, ostart = open_routine
            raise FilterInputError(
                src.name,
                f"{kind.upper()} {name} inside {okind.upper()} {oname} (line "
                f"{src.line_of(ostart)}): END{okind.upper()} is missing",
                line,
            )
        open_routine = (kind, name, m.start())
    last = src.line_of(len(code))
    if open_routine is not None:
        kind, name, start = open_routine
        raise FilterInputError(
            src.name,
            f"{kind.upper()} {name} (line {src.line_of(start)}) has no END{kind.upper()}: the "
            "module is cut short",
            last,
        )
    if done < 0:
        raise FilterInputError(src.name, "no ENDMODULE: the module is cut short", last)
    rest = code[done:].rstrip("\x1a \t\r\n")
    if rest:
        after = done + len(rest) - len(rest.lstrip())
        raise FilterInputError(
            src.name, "text after ENDMODULE (a second module?)", src.line_of(after)
        )


def _read_decls(mod: Module) -> None:
    src, code = mod.source, mod.code
    for m in DECL.finditer(code):
        prefix, kind, name = (m.group(1) or "").upper(), m.group(2).lower(), m.group(3)
        dims_text, assign = m.group(4), m.group(5)
        line = src.line_of(m.start())
        routine = mod.routine_at(m.start())
        scope = routine.name if routine is not None else ""
        dims = _dims(dims_text)
        value = fast = None
        if assign:
            i = skip_space(code, m.end())
            if kind == "robtarget" and not dims:
                fast = ROBTARGET.match(code, i)  # the common case: no Node tree needed
            if fast is None and i < len(code) and code[i] == "[":
                value = parse_literal(code, i, src)
        decl = Decl(kind, name, src.name, line, value, dims, scope, prefix == "LOCAL", fast=fast)
        if value is not None:
            _elements(value, len(dims), (), decl.elements)
            check = {"robtarget": is_robtarget, "jointtarget": is_jointtarget}.get(kind)
            for index, node in decl.elements.items():
                if check is not None and not check(node):
                    raise FilterInputError(
                        src.name,
                        f"{kind} {name}{index_text(index)}: not a {kind} literal",
                        src.line_of(node.start),
                    )
        key = (scope.lower(), name.lower())
        if key in mod.decls:
            raise FilterInputError(
                src.name, f"{name} declared twice (also line {mod.decls[key].line})", line
            )
        mod.decls[key] = decl


def lookup(
    name: str, scope: str, mod: Module, modules: list[Module], kinds: tuple[str, ...]
) -> tuple[Decl | None, str]:
    """The declaration ``name`` means in routine ``scope`` of ``mod`` (see the module
    docstring), of one of ``kinds``; or None and, where the name is ambiguous, why."""
    memo = (name.lower(), scope, kinds)
    if memo not in mod.lookups:
        mod.lookups[memo] = _find(name.lower(), scope, mod, modules, kinds)
    return mod.lookups[memo]


def _find(
    key: str, scope: str, mod: Module, modules: list[Module], kinds: tuple[str, ...]
) -> tuple[Decl | None, str]:
    for k in ((scope, key), ("", key)) if scope else (("", key),):
        d = mod.decls.get(k)
        if d is not None:
            return (d, "") if d.kind in kinds else (None, "")
    found = [
        m.decls[("", key)]
        for m in modules
        if m is not mod
        and ("", key) in m.decls
        and m.decls[("", key)].kind in kinds
        and not m.decls[("", key)].local
    ]
    if len(found) == 1:
        return found[0], ""
    if len(found) > 1:
        where = ", ".join(d.where for d in found)
        return None, f"{found[0].name} is declared in several files ({where})"
    return None, ""
