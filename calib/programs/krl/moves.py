"""The moves of a KRL ``.src`` for the filter's KUKA dialect, with the tool and base in force.

:class:`Moves` walks a ``.src`` line by line (KRL has one statement a line) and records on
every target a move uses a :class:`~calib.programs.sites.Use` with the tool and base in force
there; :mod:`calib.programs.krl.filter` documents the rules (``FDAT_ACT``, ``$TOOL``/``$BASE``,
``BAS(#TOOL/#BASE)``, ``;FOLD`` cross-checks, branches of ``IF``/``SWITCH`` and loops).
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from calib.programs.krl.data import (
    Aggregate,
    Decl,
    KrlFrame,
    Program,
    frame_of,
    index_text,
    parse_aggregate,
    unknown_frame,
)
from calib.programs.lexer import split_top
from calib.programs.sites import Configuration, Source, Target, Use

#: ``(source, name, aggregate, declared type)`` → the target (None: not a position).
MakeTarget = Callable[[Source, str, Aggregate, str], Target | None]

SET_FRAME = re.compile(r"^\s*\$(TOOL|BASE)\s*=\s*(.*?)\s*$", re.I)
NAME_REF = re.compile(r"([A-Za-z_$][\w$]*)\s*(?:\[([^\]]*)\])?")
_ROUTINE = re.compile(r"^\s*(?:GLOBAL\s+)?(?:DEF|DEFFCT\s+\w+)\s+(\w+)\s*\(", re.I)
_END = re.compile(r"^\s*END(?:FCT)?\s*$", re.I)
_MOVE = re.compile(r"^\s*(PTP|LIN|CIRC|SPTP|SLIN|SCIRC|SPL)[ \t]+(.*)$", re.I)
_REL_MOVE = re.compile(r"^\s*((?:S?PTP|S?LIN|S?CIRC)_REL)[ \t]+(.*)$", re.I)
_FDAT_ACT = re.compile(r"^\s*FDAT_ACT\s*=\s*([A-Za-z_$][\w$]*)\s*$", re.I)
_BAS = re.compile(r"^\s*BAS\s*\(\s*#(TOOL|BASE)\s*,\s*(\d+)\s*\)", re.I)
_DATA_REF = re.compile(r"(TOOL_DATA|BASE_DATA)\s*\[\s*(\d+)\s*\]$", re.I)
_WITH = re.compile(r"\bWITH\b", re.I)
_WITH_SET = re.compile(r"\s*\$(TOOL|BASE)\s*=\s*(.*)", re.I | re.S)
_FDAT_FN = re.compile(r"(STOOL2|SBASE)\s*\(\s*([A-Za-z_$][\w$]*)\s*(?:\.\s*BASE_NO\s*)?\)", re.I)
_SPLINE = re.compile(r"^\s*(?:PTP_)?SPLINE\b", re.I)
_HEAD = re.compile(r"\s*([A-Za-z_$][\w$]*)")
#: First words of the statements :meth:`Moves._statement` reads (the others are skipped), and
#: which of its patterns each can start.
_FAMILY = {
    **dict.fromkeys(("DEF", "DEFFCT", "GLOBAL"), "routine"),
    **dict.fromkeys(("END", "ENDFCT"), "end"),
    "FDAT_ACT": "fdat",
    "BAS": "bas",
    **dict.fromkeys(("$TOOL", "$BASE"), "set"),
    **dict.fromkeys(("IF", "SWITCH", "FOR", "WHILE", "LOOP", "REPEAT"), "open"),
    **dict.fromkeys(("ELSE", "CASE", "DEFAULT"), "middle"),
    **dict.fromkeys(("ENDIF", "ENDSWITCH", "ENDFOR", "ENDWHILE", "ENDLOOP", "UNTIL"), "close"),
    **dict.fromkeys(("PTP", "LIN", "CIRC", "SPTP", "SLIN", "SCIRC", "SPL"), "move"),
    **dict.fromkeys(("PTP_REL", "LIN_REL", "CIRC_REL", "SPTP_REL", "SLIN_REL", "SCIRC_REL"), "rel"),
    **dict.fromkeys(("SPLINE", "PTP_SPLINE"), "spline"),
}
_OPEN = re.compile(r"^\s*(IF|SWITCH|FOR|WHILE|LOOP|REPEAT)\b", re.I)
_MIDDLE = re.compile(r"^\s*(ELSE|CASE|DEFAULT)\b", re.I)
_CLOSE = re.compile(r"^\s*(ENDIF|ENDSWITCH|ENDFOR|ENDWHILE|ENDLOOP|UNTIL)\b", re.I)
_FOLD = re.compile(r"^\s*;\s*(END)?FOLD\b([^;\r\n]*)", re.I)
_FOLD_FRAME = re.compile(r"\b(Tool|Base)\s*\[\s*(\d+)\s*\]", re.I)


@dataclass
class _Block:
    """An open ``IF``/``SWITCH``/loop: the frames at its entry and at each branch's end."""

    entry: tuple[KrlFrame, KrlFrame]
    line: int
    kind: str
    ends: list[tuple[KrlFrame, KrlFrame]] = field(default_factory=list)
    started: bool = False
    complete: bool = False  # an ELSE or DEFAULT: some branch is always taken


class Moves:
    """The moves of one ``.src``: their targets' uses, with the tool and base in force."""

    def __init__(
        self,
        make_target: MakeTarget,
        prog: Program,
        src: Source,
        targets: dict[tuple[str, str], Target],
    ) -> None:
        self.make_target, self.prog, self.src, self.targets = make_target, prog, src, targets
        self.tool = unknown_frame("no tool set before this move in its DEF")
        self.base = unknown_frame("no base set before this move in its DEF")
        self.blocks: list[_Block] = []
        self.folds: list[tuple[int | None, int | None, int]] = []
        self.inline: list[Target] = []
        self.previous: Target | None = None
        self.code = prog.code_of(src)

    def run(self) -> list[Target]:
        raw_lines = self.src.text.split("\n")
        offset = 0
        for k, line in enumerate(self.code.split("\n")):
            if raw_lines[k].lstrip().startswith(";"):
                self._fold(raw_lines[k], k + 1)
            head = _HEAD.match(line)
            if head and (word := head.group(1).upper()) in _FAMILY:
                self._statement(line, offset, k + 1, _FAMILY[word])
            offset += len(line) + 1
        return self.inline

    def _fold(self, raw: str, line: int) -> None:
        m = _FOLD.match(raw)
        if not m:
            return
        if m.group(1):
            if self.folds:
                self.folds.pop()
            return
        found = {k.upper(): int(v) for k, v in _FOLD_FRAME.findall(m.group(2))}
        self.folds.append((found.get("TOOL"), found.get("BASE"), line))

    def _reset(self, why: str) -> None:
        self.tool = unknown_frame(f"no tool set before this move in {why}")
        self.base = unknown_frame(f"no base set before this move in {why}")
        self.blocks = []
        self.previous = None

    def _statement(self, line: str, offset: int, no: int, family: str) -> None:
        """One statement; ``family`` (of its first word, see :data:`_FAMILY`) says which of
        the patterns can match it."""
        if family == "routine" and (m := _ROUTINE.match(line)):
            self._reset(f"DEF {m.group(1)}")
        elif family == "end" and _END.match(line):
            self._reset("its DEF")
        elif family == "fdat" and (m := _FDAT_ACT.match(line)):
            self._fdat(m.group(1), no)
        elif family == "bas" and (m := _BAS.match(line)):
            table = "TOOL_DATA" if m.group(1).upper() == "TOOL" else "BASE_DATA"
            self._set(m.group(1).upper(), self.prog.table(table, int(m.group(2))))
        elif family == "set" and (m := SET_FRAME.match(line)):
            self._set(m.group(1).upper(), self._frame_value(m.group(2), offset + m.start(2), no))
        elif family == "open" and (m := _OPEN.match(line)):
            self.blocks.append(_Block((self.tool, self.base), no, m.group(1).upper()))
        elif family == "middle" and (m := _MIDDLE.match(line)) and self.blocks:
            blk = self.blocks[-1]
            if blk.kind in ("IF", "SWITCH"):
                if not (blk.kind == "SWITCH" and not blk.ends and not blk.started):
                    blk.ends.append((self.tool, self.base))
                blk.started = True
                blk.complete |= m.group(1).upper() in ("ELSE", "DEFAULT")
                self.tool, self.base = blk.entry
        elif family == "close" and _CLOSE.match(line) and self.blocks:
            self._close()
        elif family == "move" and (m := _MOVE.match(line)):
            rest, at = m.group(2), offset + m.start(2)
            if w := _WITH.search(rest):
                self._with(rest[w.end() :], at + w.end(), no)
                rest = rest[: w.start()]
            self._move(m.group(1).upper(), rest, at, no)
        elif family == "rel" and (m := _REL_MOVE.match(line)):
            self._relative(m.group(1).upper(), m.group(2), no)
        elif family == "spline" and _SPLINE.match(line) and (w := _WITH.search(line)):
            self._with(line[w.end() :], offset + w.end(), no)

    def _set(self, which: str, value: KrlFrame) -> None:
        if which == "TOOL":
            self.tool = value
        else:
            self.base = value

    def _close(self) -> None:
        blk = self.blocks.pop()
        ends = [*blk.ends, (self.tool, self.base)]
        if not blk.complete:  # a loop may run zero times; an IF without ELSE may do nothing
            ends.append(blk.entry)
        merged = []
        for k, what in ((0, "tool"), (1, "base")):
            first = ends[0][k]
            if all(first.same(e[k]) for e in ends[1:]):
                merged.append(first)
            else:
                merged.append(
                    unknown_frame(
                        f"the {what} differs between the paths through the "
                        f"{blk.kind} at line {blk.line}"
                    )
                )
        self.tool, self.base = merged[0], merged[1]

    def _fdat(self, name: str, no: int, which: tuple[str, ...] = ("TOOL", "BASE")) -> None:
        """Set the tool and/or base from the ``FDAT`` ``name`` (``FDAT_ACT=``, ``STOOL2``,
        ``SBASE``)."""
        decl = self.prog.lookup(name, self.src.name)
        why = ""
        if decl is None or decl.kind != "FDAT" or decl.value is None:
            why = f"FDAT {name} (line {no}) is not declared in the given .dat files"
        elif (ipo := decl.value.items.get("IPO_FRAME")) and ipo.text.upper() == "#TCP":
            why = f"FDAT {name}: external TCP (IPO_FRAME #TCP) not supported"
        if why:
            self.tool, self.base = unknown_frame(why), unknown_frame(why)
            return
        assert decl is not None and decl.value is not None
        for key, table, what in (
            ("TOOL_NO", "TOOL_DATA", "TOOL"),
            ("BASE_NO", "BASE_DATA", "BASE"),
        ):
            item = decl.value.items.get(key)
            if what not in which:
                continue
            if item is None or item.num is None:
                self._set(what, unknown_frame(f"FDAT {name} has no numeric {key}"))
            else:
                self._set(what, self.prog.table(table, int(item.num)))

    def _with(self, text: str, at: int, no: int) -> None:
        """The ``$TOOL``/``$BASE`` assignments of a ``WITH`` clause (spline inline forms:
        ``$TOOL = STOOL2(FP1), $BASE = SBASE(FP1.BASE_NO)``) starting at offset ``at``."""
        for a, b in _top_level_spans(text):
            m = _WITH_SET.match(text, a, b)
            if not m:
                continue
            which, expr = m.group(1).upper(), m.group(2).strip()
            if f := _FDAT_FN.fullmatch(expr):
                self._fdat(f.group(2), no, (which,))
            else:
                self._set(which, self._frame_value(expr, at + m.start(2), no))

    def _frame_value(self, expr: str, at: int, no: int) -> KrlFrame:
        if m := _DATA_REF.fullmatch(expr):
            return self.prog.table(m.group(1).upper(), int(m.group(2)))
        if expr.upper() in ("$NULLFRAME", "$WORLD"):
            return KrlFrame(expr.upper(), np.eye(4), "")
        if expr.startswith("{"):
            agg = parse_aggregate(self.code, at, self.src)
            value, why = frame_of(agg, f"the frame at line {no}", self.src)
            return KrlFrame(f"frame@{no}", value, why)
        r = NAME_REF.fullmatch(expr)
        decl = self.prog.lookup(r.group(1), self.src.name) if r and not r.group(2) else None
        if decl is not None and decl.value is not None and decl.kind in ("FRAME", "POS", "E6POS"):
            value, why = frame_of(decl.value, decl.name, self.prog.data[decl.file].source)
            return KrlFrame(decl.name, value, why)
        return unknown_frame(f"line {no}: {expr[:40]} cannot be resolved to a frame")

    def _move(self, kind: str, rest: str, at: int, no: int) -> None:
        """A move whose arguments ``rest`` start at offset ``at`` of the file."""
        n_targets = 2 if kind in ("CIRC", "SCIRC") else 1
        fold_problem = self._fold_check(no)
        tool, base = self.tool, self.base
        problem = "; ".join(
            dict.fromkeys(p for p in (tool.problem, base.problem, fold_problem) if p)
        )
        use = Use(self.src.name, no, tool.name, base.name, tool.value, base.value, problem)
        for a, b in _top_level_spans(rest)[:n_targets]:
            part = rest[a:b]
            lead = len(part) - len(part.lstrip())
            self._use_part(part.strip(), at + a + lead, use, no)

    def _fold_check(self, no: int) -> str:
        for tool_no, base_no, line in reversed(self.folds):
            if tool_no is None and base_no is None:
                continue
            for want, have, label in (
                (tool_no, self.tool, "TOOL_DATA"),
                (base_no, self.base, "BASE_DATA"),
            ):
                if want is None or have.value is None:
                    continue
                expect = f"{label}[{want}]"
                if have.name != expect:
                    return (
                        f"the FOLD at line {line} says {label.split('_')[0].title()}[{want}] "
                        f"but {have.name} is in force"
                    )
            return ""
        return ""

    def _use_part(self, part: str, at: int, use: Use, no: int) -> None:
        if part.startswith("{"):
            agg = parse_aggregate(self.code, at, self.src)
            t = self.make_target(self.src, f"inline@{no}", agg, "")
            if t is None:
                return
            self._chain(t)
            t.uses.append(use)
            self.inline.append(t)
            return
        m = NAME_REF.match(part)
        if not m:
            return
        name, index = m.group(1), m.group(2)
        tail = part[m.end() :].strip()
        expression = tail.startswith(":") or part.startswith(":")
        decl = self.prog.lookup(name, self.src.name)
        if decl is None:
            return
        for t in self._named(decl, name, index):
            if expression:
                u = Use(
                    use.file,
                    use.line,
                    use.tool_name,
                    use.work_name,
                    use.tool,
                    use.work,
                    f"used in the expression {part[:40]!r}: the robot does not go to the "
                    "target itself",
                )
                t.uses.append(u)
            else:
                self._chain(t)
                t.uses.append(use)

    def _named(self, decl: Decl, name: str, index: str | None) -> list[Target]:
        """The targets ``name[index]`` names (every element for a variable index)."""
        if index is None:
            keys = (
                [name.upper()]
                if decl.value is not None
                else [(decl.name + index_text(i)).upper() for i in decl.elements]
            )
        else:
            try:
                idx = tuple(int(v) for v in index.split(","))
                keys = [(decl.name + index_text(idx)).upper()]
            except ValueError:
                keys = [(decl.name + index_text(i)).upper() for i in decl.elements]
        found = (self.targets.get((decl.file, key)) for key in keys)
        return [t for t in found if t is not None]

    def _relative(self, kind: str, rest: str, no: int) -> None:
        """A ``_REL`` move: its named targets are offsets, not poses (left unchanged)."""
        for a, b in _top_level_spans(rest)[: 2 if "CIRC" in kind else 1]:
            m = NAME_REF.match(rest[a:b].strip())
            decl = self.prog.lookup(m.group(1), self.src.name) if m else None
            if m is None or decl is None:
                continue
            for t in self._named(decl, m.group(1), m.group(2)):
                t.problem = t.problem or (f"line {no}: {kind} moves by it: an offset, not a pose")

    def _chain(self, t: Target) -> None:
        """A Cartesian target without S and T takes the branch nearest the previous move's
        target (same file only: the core looks it up there)."""
        c = t.configuration
        if (
            t.kind == "cartesian"
            and c is not None
            and c.shoulder is None
            and np.all(np.isinf(c.joint_ranges_deg))
            and self.previous is not None
            and self.previous.file == t.file
            and not t.uses
        ):
            t.configuration = Configuration(after=self.previous.name, text="(none)")
        self.previous = t


def _top_level_spans(text: str) -> list[tuple[int, int]]:
    """Spans of ``text`` split at commas outside braces, brackets and parentheses."""
    return split_top(text, 0, len(text))
