"""RAPID's syntax for the filter: bracketed literals parsed with the character span of every
number, on the shared lexer (:mod:`calib.programs.lexer`: comments and strings blanked,
numbers, brackets, argument lists split at depth 0).

The text is never changed: :func:`blank` replaces comments (``!`` to the end of the line) and
strings by spaces of the same length, so an offset into the blanked code is an offset into
the file's text.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from calib.kinematics import FloatArray
from calib.programs import lexer
from calib.programs.lexer import RAPID
from calib.programs.rotations import frame, quat_wxyz_to_matrix
from calib.programs.sites import FilterInputError, Num, Source

#: Bound of every number's magnitude the filter reads (a RAPID ``num`` is a 32-bit float;
#: ``9E+09`` marks an external axis that is not there); its length is the lexer's bound.
MAX_NUMBER_ABS = 1e15
_WORD = re.compile(r"[A-Za-z_]\w*")
#: ``text`` with comments (``!`` to the end of the line) and strings replaced by spaces,
#: same length, so offsets into it are offsets into ``text``.
blank = RAPID.blank
skip_space = lexer.skip_space
_bounded = lexer.bounded


@dataclass(slots=True)
class Node:
    """A parsed literal: a list of nodes, a number, or another token (TRUE, an empty string)."""

    start: int
    end: int
    items: list[Node] | None = None
    num: float | None = None
    word: str = ""

    def is_list(self, n: int | None = None) -> bool:
        return self.items is not None and (n is None or len(self.items) == n)

    def numbers(self) -> bool:
        return self.items is not None and all(i.num is not None for i in self.items)


_N = r"\s*(" + lexer.NUMBER_PATTERN + r")\s*"
_SHAPE = (3, 4, 4, 6)
#: A robtarget literal of plain numbers, the common case, read by one regular expression.
ROBTARGET = re.compile(
    r"\[\s*" + r"\s*,\s*".join(r"\[" + ",".join([_N] * k) + r"\]" for k in _SHAPE) + r"\s*\]"
)


def number(text: str, source: Source, offset: int) -> float:
    """The value of a number's text at ``offset``, bounded (the lexer's length,
    :data:`MAX_NUMBER_ABS`).

    Raises
    ------
    FilterInputError
        Naming the file and line of a number too long, too large or not finite.
    """
    value = _bounded(text, MAX_NUMBER_ABS)
    if value is None:
        raise FilterInputError(
            source.name,
            f"number {lexer.shown(text)} is out of range (at most {lexer.MAX_NUMBER_CHARS} "
            f"characters and {MAX_NUMBER_ABS:g} in magnitude)",
            source.line_of(offset),
        )
    return value


def _fast_robtarget(code: str, i: int, source: Source) -> Node | None:
    m = ROBTARGET.match(code, i)
    if m is None:
        return None
    leaves = [
        Node(m.start(g), m.end(g), num=number(m.group(g), source, m.start(g))) for g in range(1, 18)
    ]
    items, k = [], 0
    for n in _SHAPE:
        group = leaves[k : k + n]
        items.append(Node(group[0].start, group[-1].end, items=group))
        k += n
    return Node(m.start(), m.end(), items=items)


def parse_literal(code: str, i: int, source: Source) -> Node:
    """The bracketed literal starting at ``code[i]`` (``[`` expected).

    Raises
    ------
    FilterInputError
        Naming the line of the first character that does not fit.
    """
    i = skip_space(code, i)
    if i >= len(code) or code[i] != "[":
        raise FilterInputError(source.name, "expected '[' (a literal value)", source.line_of(i))
    fast = _fast_robtarget(code, i, source)
    if fast is not None:
        return fast
    start = i
    items: list[Node] = []
    i += 1
    while True:
        i = skip_space(code, i)
        if i < len(code) and code[i] == "]" and not items:
            return Node(start, i + 1, items=items)
        if i < len(code) and code[i] == "[":
            node = parse_literal(code, i, source)
        else:
            m = lexer.NUMBER.match(code, i)
            if m:
                node = Node(i, m.end(), num=number(m.group(), source, i))
            else:
                w = _WORD.match(code, i)
                if w:
                    node = Node(i, w.end(), word=w.group())
                elif i < len(code) and code[i] in ",]":  # a blanked string ""
                    node = Node(i, i, word="")
                else:
                    got = code[i] if i < len(code) else "end of file"
                    raise FilterInputError(
                        source.name, f"unexpected {got!r} in a literal", source.line_of(i)
                    )
        items.append(node)
        i = skip_space(code, node.end)
        if i < len(code) and code[i] == ",":
            i += 1
            continue
        if i < len(code) and code[i] == "]":
            return Node(start, i + 1, items=items)
        got = code[i] if i < len(code) else "end of file"
        raise FilterInputError(
            source.name, f"expected ',' or ']' in a literal, got {got!r}", source.line_of(i)
        )


def nums(node: Node, source: Source) -> list[Num]:
    assert node.items is not None
    return [
        Num(source.name, n.start, n.end, source.text[n.start : n.end], float(n.num or 0.0))
        for n in node.items
    ]


def is_robtarget(node: Node) -> bool:
    if not node.is_list(4):
        return False
    assert node.items is not None
    return all(
        it.is_list(k) and it.numbers() for it, k in zip(node.items, (3, 4, 4, 6), strict=True)
    )


def is_jointtarget(node: Node) -> bool:
    if not node.is_list(2):
        return False
    assert node.items is not None
    return all(it.is_list(6) and it.numbers() for it in node.items)


def is_pose(node: Node) -> bool:
    if not node.is_list(2):
        return False
    assert node.items is not None
    return (
        node.items[0].is_list(3)
        and node.items[1].is_list(4)
        and all(it.numbers() for it in node.items)
    )


def pose(node: Node) -> FloatArray:
    assert node.items is not None and node.items[0].items and node.items[1].items
    pos = np.array([float(i.num or 0.0) for i in node.items[0].items])
    quat = np.array([float(i.num or 0.0) for i in node.items[1].items])
    return frame(pos, quat_wxyz_to_matrix(quat))


def split_options(code: str, start: int, end: int) -> tuple[tuple[int, int], list[str]]:
    """An argument's positional part (span) and its ``\\Option[:=value]`` texts."""
    if code.find("\\", start, end) < 0:
        return (start, end), []
    cuts = lexer.cuts_top(code, "\\", start, end)
    if not cuts:
        return (start, end), []
    opts = [code[a + 1 : b].strip() for a, b in zip(cuts, [*cuts[1:], end], strict=True)]
    return (start, cuts[0]), opts


def statement_end(code: str, i: int) -> int:
    """The ``;`` ending the statement that starts at ``i`` (RAPID has no ``;`` inside a
    bracket outside strings, which are blanked), or the end of the code."""
    return lexer.find_top(code, ";", i)
