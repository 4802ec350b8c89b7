"""The line-by-line state machine the program readers (KRL, RAPID, URScript) share.

Each reader names its states and gives one handler per state; a handler takes a statement
(comment stripped, not blank) and its 1-based line number, records what it read in a
:class:`Collected` and returns the next state. :func:`parse_lines` runs them:

- it starts in ``"outside"`` and must end in ``"done"``; a statement after ``"done"`` is an
  error (``text after END``), and so is a text that stops early (``missing END``, naming the
  last line);
- a whole-line comment is skipped, and kept as a header comment while the reader is in its
  header state and no move has been read yet (the plan, robot and date a writer puts there);
- a dwell before the first move is an error (:meth:`Collected.dwell`), and so is a program
  without moves (:meth:`Collected.program`).

Standard library only, like the rest of :mod:`calib.programs`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

from calib.programs.common import JointProgram, Joints, ProgramError
from calib.programs.lexer import Lexicon

#: A state's handler: (statement, line number) → the next state.
Handler = Callable[[str, int], str]


@dataclass
class Collected:
    """What a reader has read so far: the program's name, its moves (shape (n, 6) [deg]),
    the dwells [s], the header comments and the last speed setting [% of the maximum], if
    the format has one."""

    name: str = ""
    moves: list[Joints] = field(default_factory=list)
    dwells: list[float] = field(default_factory=list)
    comments: list[str] = field(default_factory=list)
    speed_pct: float | None = None

    def dwell(self, seconds: float, line_no: int, wait: str, move: str) -> None:
        """Record a dwell of ``seconds``; ``ProgramError`` when no move came before it
        (``"line 7: WAIT SEC before the first PTP"``, with ``wait`` and ``move`` the
        format's words)."""
        if not self.moves:
            raise ProgramError(f"line {line_no}: {wait} before the first {move}")
        self.dwells.append(seconds)

    def program(self, speed_pct: float, no_moves: str) -> JointProgram:
        """The program read, at ``speed_pct``, dwelling the shortest dwell read (0 without
        any); ``ProgramError(no_moves)`` when it has no move."""
        if not self.moves:
            raise ProgramError(no_moves)
        return JointProgram(
            name=self.name,
            joints_deg=tuple(self.moves),
            speed_pct=speed_pct,
            dwell_s=min(self.dwells) if self.dwells else 0.0,
            comments=tuple(self.comments),
        )


def parse_lines(
    text: str,
    got: Collected,
    *,
    lexicon: Lexicon,
    inline_comments: bool,
    header_state: str,
    handlers: Mapping[str, Handler],
    missing: Mapping[str, str],
    end: str,
) -> None:
    """Run the handlers over ``text``'s lines (see the module docstring).

    ``lexicon`` is the language's (:mod:`calib.programs.lexer`); with ``inline_comments`` a
    comment also ends a statement (``PTP {…} ; note``), else only a whole line is a comment.
    ``missing`` names, for each state the text may stop in, what is missing; ``end`` is the
    closing word after which nothing may follow.
    """
    state = "outside"
    for line_no, raw in enumerate(text.splitlines(), start=1):
        note = lexicon.comment_of(raw)
        if note is not None:
            if state == header_state and not got.moves:
                got.comments.append(note)
            continue
        stmt = lexicon.code_of(raw).strip() if inline_comments else raw.strip()
        if not stmt:
            continue
        if state == "done":
            raise ProgramError(f"line {line_no}: text after {end}: {stmt!r}")
        state = handlers[state](stmt, line_no)
    if state != "done":
        raise ProgramError(f"line {len(text.splitlines())}: missing {missing[state]}")
