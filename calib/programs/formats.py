"""The controller languages' registry: each language's name, file suffixes, line ending,
help text and modules; their one home.

Standard library only and nothing imported from the writers or the filter's dialects, so the
command line builds its ``--format`` choice and its help from here without loading them
(``cablecal --help`` stays light). Every other place (the writers' registry
:mod:`calib.programs.registry`, the filter's :mod:`calib.programs.dialects`, the CLI, the
API and the page through ``GET /programs/languages``) reads these records; none keeps a
list of its own.
"""

from __future__ import annotations

import re
from dataclasses import dataclass


@dataclass(frozen=True)
class Language:
    """One controller language.

    Attributes
    ----------
    name : str
        The format's name (``--format``, the REST enum, the filter's dialect name).
    title : str
        What it is, for help texts and the page (``ABB RAPID module``).
    suffix : str
        The suffix of a program cablecal writes (Fanuc's controller file names are upper
        case: ``.LS``).
    extensions : tuple of str
        Lower-case extensions, with the dot, of the files the filter reads as this language.
    files : str
        The files the filter takes, in the operator's words (help texts and the page).
    newline : str
        The line ending of a program cablecal writes, from the command line and the API
        alike (Fanuc's ``.LS`` is CRLF, as its controllers write it).
    program_module, filter_module : str
        The writer and the filter dialect (imported on first use).
    label, looks : str
        What its text is (``an ABB RAPID module``) and the feature that shows it (``a MODULE
        statement``), for messages.
    signature : re.Pattern
        What its text starts with, searched in a file's first :data:`SNIFF_CHARS` characters:
        the filter refuses a file whose content is another language's than its extension
        says, and the simulator tells a program from a CSV by it.
    """

    name: str
    title: str
    suffix: str
    extensions: tuple[str, ...]
    files: str
    newline: str
    program_module: str
    filter_module: str
    label: str
    looks: str
    signature: re.Pattern[str]

    def with_newline(self, text: str) -> str:
        """A writer's ``\\n``-ended ``text`` with this language's line ending."""
        return text if self.newline == "\n" else text.replace("\n", self.newline)


#: Characters of a file's start a signature looks at (headers and comments come first).
SNIFF_CHARS = 65536

#: The languages, in the order the CLI, the REST enum and the page list them.
LANGUAGES: dict[str, Language] = {
    lang.name: lang
    for lang in (
        Language(
            "rapid",
            "ABB RAPID module",
            ".mod",
            (".mod", ".modx", ".prg", ".sys"),
            "RAPID .mod/.modx/.prg/.sys with their tool data",
            "\n",
            "calib.programs.rapid.program",
            "calib.programs.rapid.filter",
            "an ABB RAPID module",
            "a MODULE statement",
            re.compile(
                r"\A\ufeff?(?:\s*(?:%%%[\s\S]*?%%%|![^\n]*))*\s*MODULE\s+\w+", re.IGNORECASE
            ),
        ),
        Language(
            "urscript",
            "UR URScript",
            ".script",
            (".script", ".urscript"),
            "URScript .script/.urscript",
            "\n",
            "calib.programs.urscript.program",
            "calib.programs.urscript.filter",
            "a URScript program",
            "a def NAME(): or a move to a pose",
            re.compile(
                r"^[ \t]*def[ \t]+\w+[ \t]*\([^)\n]*\)[ \t]*:"
                r"|\b(?:movej|movel|movep|movec)\s*\(\s*p?\[",
                re.MULTILINE,
            ),
        ),
        Language(
            "krl",
            "KUKA KRL",
            ".src",
            (".src", ".dat"),
            "KRL .src/.dat with $config.dat",
            "\n",
            "calib.programs.krl.program",
            "calib.programs.krl.filter",
            "a KUKA KRL program",
            "a &ACCESS header, DEF or DEFDAT",
            re.compile(
                r"\A\ufeff?(?:\s*(?:&[^\n]*|;[^\n]*))*\s*"
                r"(?:&\w+|DEFDAT\s+\w+|(?:GLOBAL\s+)?DEF(?:FCT\s+\w+)?\s+\w+\s*"
                r"\([^)\n]*\)(?![ \t]*:))",
                re.IGNORECASE,
            ),
        ),
        Language(
            "fanuc-ls",
            "Fanuc TP (ASCII)",
            ".LS",
            (".ls",),
            "Fanuc .ls",
            "\r\n",
            "calib.programs.fanuc.program",
            "calib.programs.fanuc.filter",
            "a Fanuc LS program",
            "a /PROG line and /ATTR, /MN or /POS sections",
            re.compile(r"\A\ufeff?\s*/PROG\b[\s\S]*?^[ \t]*/(?:ATTR|MN|POS)\b", re.MULTILINE),
        ),
    )
}

#: Controller program formats, in the order the CLI, the REST enum and the page list them.
PROGRAM_FORMATS: tuple[str, ...] = tuple(LANGUAGES)

#: What ``GET /campaigns/{id}/plan?format=`` and the compensated-target download serve.
DOWNLOAD_FORMATS: tuple[str, ...] = ("csv", *PROGRAM_FORMATS)

#: File suffix per download format.
SUFFIX: dict[str, str] = {"csv": ".csv", **{n: lang.suffix for n, lang in LANGUAGES.items()}}

#: What each download format is, for help texts and the page.
TITLE: dict[str, str] = {
    "csv": "joint-target CSV",
    **{n: lang.title for n, lang in LANGUAGES.items()},
}


def looks_like(text: str) -> list[tuple[str, int]]:
    """The languages whose signature the text's start matches: (name, line of the match's
    end), in registry order."""
    head = text[:SNIFF_CHARS]
    out = []
    for name, lang in LANGUAGES.items():
        m = lang.signature.search(head)
        if m:
            out.append((name, head.count("\n", 0, m.end()) + 1))  # the head's lines only
    return out


def filter_files_help() -> str:
    """The files ``cablecal filter`` takes, every language's (help texts and the page)."""
    return ", ".join(lang.files for lang in LANGUAGES.values())


#: The robot maker whose controllers run each format (the robot library's ``# maker:`` words,
#: lower case: :func:`calib.robots.files.library_info`): the filter warns when a program's
#: format is not the robot's maker's.
MAKER: dict[str, str] = {
    "rapid": "abb",
    "urscript": "ur",
    "krl": "kuka",
    "fanuc-ls": "fanuc",
}

#: Default joint speed of a program [% of the robot's maximum]: calm moves, short campaign.
DEFAULT_SPEED_PCT = 25.0

#: Settle windows in a dwell: one for the arm to stop ringing after the fine stop, one for
#: the sampler to see it still (``settle_s``), one spare for a slow poll or a retried read.
DWELL_SETTLE_WINDOWS = 3
#: Added to the dwell for the capture itself (average, store) [s].
DWELL_MARGIN_S = 0.5


def dwell_s_for_settle(settle_s: float) -> float:
    """Default dwell at each pose [s] for a sampler settle window ``settle_s`` [s]:
    :data:`DWELL_SETTLE_WINDOWS` windows plus :data:`DWELL_MARGIN_S`, rounded up to 0.1 s."""
    if not settle_s > 0:
        raise ValueError(f"settle_s: must be > 0, got {settle_s}")
    tenths = DWELL_SETTLE_WINDOWS * settle_s * 10 + DWELL_MARGIN_S * 10
    return float(-(-round(tenths, 6) // 1)) / 10
