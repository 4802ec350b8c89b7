"""The identification options as the page reads them (``GET /options/identify``).

Every figure comes from :mod:`calib.options` (names, defaults, bounds, choices, help), the
fields from :class:`daemon.api.schemas.IdentificationRequest`, which of them come first from
:data:`MAIN_FIELDS` and the job states from :class:`daemon.store.JobState`: the page builds
its form and its checks from this answer and keeps no copy of them.
"""

from __future__ import annotations

from typing import Any, Final, Literal

from typing_extensions import TypedDict

from calib.options import default, spec
from daemon.api.schemas import IdentificationRequest
from daemon.store import JOB_FINISHED, JobState

OptionType = Literal["choice", "bool", "int", "float", "names"]

#: The options the page shows first, the ones most identifications set (the method, the
#: hold-out and its seed, the robust mode, the prior); the others go under "More options".
MAIN_FIELDS: Final = ("method", "test_fraction", "holdout", "robust", "seed", "prior")


class OptionField(TypedDict):
    """One body field: ``type`` choice, bool, int, float or names (a list of parameter
    names); ``default``; the bounds (null when unbounded) and ``choices`` (null unless a
    choice); ``help`` (with the unit in brackets)."""

    name: str
    type: OptionType
    default: Any
    gt: float | None
    ge: float | None
    lt: float | None
    le: float | None
    choices: list[str] | None
    help: str


class IdentifyOptionsSpec(TypedDict):
    """The body fields in form order, the ones the page shows first (``main_fields``), and
    the job states (``finished``: no further change)."""

    fields: list[OptionField]
    main_fields: list[str]
    job_states: list[str]
    finished_states: list[str]


def _type(value: Any, choices: object) -> OptionType:
    if choices is not None:
        return "choice"
    if isinstance(value, bool):
        return "bool"
    if isinstance(value, int):
        return "int"
    if isinstance(value, float):
        return "float"
    return "names"


def identify_options_spec(noise_mm: float | None = None) -> IdentifyOptionsSpec:
    """The spec; ``noise_mm`` is the daemon's configured noise, if set (else calib's)."""
    out: list[OptionField] = []
    for name in IdentificationRequest.model_fields:
        sp = spec(name)
        value = default(name)
        if name == "noise_mm" and noise_mm is not None:
            value = noise_mm
        out.append(
            {
                "name": name,
                "type": _type(value, sp.choices),
                "default": list(value) if isinstance(value, tuple) else value,
                "gt": sp.gt,
                "ge": sp.ge,
                "lt": sp.lt,
                "le": sp.le,
                "choices": None if sp.choices is None else list(sp.choices),
                "help": sp.help,
            }
        )
    return {
        "fields": out,
        "main_fields": list(MAIN_FIELDS),
        "job_states": [s.value for s in JobState],
        "finished_states": [s.value for s in JobState if s in JOB_FINISHED],
    }
