"""CSV text cells: the one guard against formula injection in every CSV cablecal writes.

A spreadsheet runs a cell that starts with ``=``, ``+``, ``-``, ``@``, a tab or a CR as a
formula (OWASP "CSV injection"). Every CSV with text in it is written by :func:`write_csv`,
which puts one ``'`` before such a text cell (:func:`neutralise_cell`); every reader drops it
again (:func:`restore_cell`), so a round trip keeps the name. Standard library only, so
:mod:`calib.programs` (which reads plans) stays light.
"""

from __future__ import annotations

import csv
import io
import re
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

#: A text cell a spreadsheet would run as a formula (OWASP "CSV injection"): it starts, after
#: any number of ``'``, with ``=``, ``+``, ``-``, ``@``, a tab or a CR.
_FORMULA_LIKE = re.compile("'*[=+\\-@\t\r]")


def neutralise_cell(text: str) -> str:
    """A text cell (``anchor``, ``group``) as an export writes it: one ``'`` put in front of
    a formula-like cell (``=1+2`` -> ``'=1+2``), so a spreadsheet shows it as text. Numbers
    are written by the exporters themselves (``-12.5`` stays ``-12.5``) and never pass here.
    :func:`restore_cell` reverses it exactly, also for a name that itself starts with ``'``."""
    return "'" + text if _FORMULA_LIKE.match(text) else text


def write_csv(rows: Iterable[Mapping[str, Any]], columns: Sequence[str]) -> str:
    """CSV text (header ``columns``, ``\n`` line ends) of ``rows``, the one writer of every
    CSV cablecal gives out with text in it (samples, plans, verification residuals): each
    text cell goes through :func:`neutralise_cell`; numbers are written as they are, so a
    number must not be passed pre-formatted as text."""
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(columns), lineterminator="\n")
    writer.writeheader()
    for row in rows:
        cells = {k: neutralise_cell(v) if isinstance(v, str) else v for k, v in row.items()}
        writer.writerow(cells)
    return buf.getvalue()


def restore_cell(text: str) -> str:
    """The inverse of :func:`neutralise_cell`, applied by every reader of cablecal's CSVs to
    their text columns (:func:`calib.dataset.parse_samples_csv`, a plan's ``anchor`` in
    :func:`calib.programs.common.read_targets_csv`): one leading ``'`` is dropped when a
    formula-like cell follows it."""
    return text[1:] if text.startswith("'") and _FORMULA_LIKE.match(text, 1) else text
