"""The fields of ``result.json`` as typed blocks, and their readers: each checks a value's
type and raises a :class:`ResultError` naming the field (:mod:`calib.result` assembles them).
Standard library only. Units as in the document: lengths in mm, angles in degrees."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any


class ResultError(ValueError):
    """A ``result.json`` field is missing or of the wrong type; ``field`` names it
    (``dh[2].a_mm``: the third row's ``a_mm``)."""

    def __init__(self, field_name: str, message: str) -> None:
        super().__init__(f"{field_name}: {message}")
        self.field = field_name


# --------------------------------------------------------------------------- field readers
def number(value: Any, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ResultError(name, f"must be a number, got {value!r}")
    return float(value)


def opt_number(doc: Mapping[str, Any], key: str, name: str) -> float | None:
    value = doc.get(key)
    return None if value is None else number(value, name)


def integer(value: Any, name: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ResultError(name, f"must be an integer, got {value!r}")
    return value


def opt_int(doc: Mapping[str, Any], key: str, name: str) -> int | None:
    value = doc.get(key)
    return None if value is None else integer(value, name)


def opt_str(doc: Mapping[str, Any], key: str, name: str) -> str | None:
    value = doc.get(key)
    if value is not None and not isinstance(value, str):
        raise ResultError(name, f"must be text, got {value!r}")
    return value


def opt_bool(doc: Mapping[str, Any], key: str, name: str) -> bool | None:
    value = doc.get(key)
    if value is not None and not isinstance(value, bool):
        raise ResultError(name, f"must be true or false, got {value!r}")
    return value


def opt_map(doc: Mapping[str, Any], key: str, name: str) -> Mapping[str, Any] | None:
    value = doc.get(key)
    if value is not None and not isinstance(value, Mapping):
        raise ResultError(name, f"must be an object, got {value!r}")
    return value


def as_list(value: Any, name: str) -> Sequence[Any]:
    if not isinstance(value, list | tuple):
        raise ResultError(name, f"must be a list, got {value!r}")
    return value


def numbers(value: Any, name: str) -> tuple[float, ...]:
    return tuple(number(v, f"{name}[{i}]") for i, v in enumerate(as_list(value, name)))


def integers(value: Any, name: str) -> tuple[int, ...]:
    return tuple(integer(v, f"{name}[{i}]") for i, v in enumerate(as_list(value, name)))


def point(value: Any, name: str) -> tuple[float, float, float]:
    x = numbers(value, name)
    if len(x) != 3:
        raise ResultError(name, f"must hold 3 numbers (x, y, z in mm), got {len(x)}")
    return x[0], x[1], x[2]


# --------------------------------------------------------------------------------- blocks
@dataclass(frozen=True)
class DhRow:
    """One joint's row of the DH table: ``joint`` (1-based), angles [deg], lengths [mm]."""

    joint: int
    alpha_deg: float
    a_mm: float
    d_mm: float
    theta_deg: float

    @classmethod
    def from_json(cls, row: Any, index: int, name: str) -> DhRow:
        where = f"{name}[{index}]"
        if not isinstance(row, Mapping):
            raise ResultError(where, f"must be an object, got {row!r}")
        joint = row.get("joint", index + 1)
        return cls(
            integer(joint, f"{where}.joint"),
            *(number(row.get(k), f"{where}.{k}") for k in DH_KEYS),
        )

    def to_json(self) -> dict[str, float | int]:
        """The row as ``result.json`` writes it."""
        return {"joint": self.joint, **dict(zip(DH_KEYS, self.values(), strict=True))}

    def values(self) -> tuple[float, float, float, float]:
        """``(alpha_deg, a_mm, d_mm, theta_deg)``."""
        return self.alpha_deg, self.a_mm, self.d_mm, self.theta_deg


#: The four numbers of a DH row, in the table's column order.
DH_KEYS = ("alpha_deg", "a_mm", "d_mm", "theta_deg")


@dataclass(frozen=True)
class AnchorFit:
    """An anchor's fitted cable exit ``anchor_mm`` (x, y, z) [mm, base frame] and the
    indicator's zero offset ``length_offset_mm`` [mm]."""

    anchor_mm: tuple[float, float, float]
    length_offset_mm: float


@dataclass(frozen=True)
class Split:
    """The train/test split: how it was chosen and the test rows (0-based; absent before
    shape 4), with their sample ids when the daemon stored the result."""

    holdout: str | None
    test_fraction: float | None
    seed: int | None
    n_train: int | None
    n_test: int | None
    test_rows: tuple[int, ...] | None
    test_sample_ids: tuple[int, ...] | None

    @classmethod
    def from_json(cls, block: Mapping[str, Any]) -> Split:
        rows, ids = block.get("test_rows"), block.get("test_sample_ids")
        return cls(
            holdout=opt_str(block, "holdout", "split.holdout"),
            test_fraction=opt_number(block, "test_fraction", "split.test_fraction"),
            seed=opt_int(block, "seed", "split.seed"),
            n_train=opt_int(block, "n_train", "split.n_train"),
            n_test=opt_int(block, "n_test", "split.n_test"),
            test_rows=None if rows is None else integers(rows, "split.test_rows"),
            test_sample_ids=None if ids is None else integers(ids, "split.test_sample_ids"),
        )


@dataclass(frozen=True)
class Correlation:
    """The correlation matrix (k, k) of the solved parameters ``names``."""

    names: tuple[str, ...]
    matrix: tuple[tuple[float, ...], ...]

    @classmethod
    def from_json(cls, block: Mapping[str, Any]) -> Correlation:
        names = as_list(block.get("names", []), "correlation.names")
        if not all(isinstance(n, str) for n in names):
            raise ResultError("correlation.names", "must be a list of parameter names")
        matrix = as_list(block.get("matrix", []), "correlation.matrix")
        rows = tuple(numbers(r, f"correlation.matrix[{i}]") for i, r in enumerate(matrix))
        return cls(tuple(names), rows)


@dataclass(frozen=True)
class Prior:
    """The prior block: whether the prior was asked (``used``) and the noise the fit ran
    with [mm]; ``block`` is the whole block (widths, how the weight was chosen)."""

    used: bool | None
    noise_mm: float | None
    block: Mapping[str, Any]


@dataclass(frozen=True)
class Drift:
    """The measurement's drift block (:func:`calib.identify.result_json.drift_report`):
    ``per_sample_mm`` (n,) [mm] when identify put it there; ``block`` is the whole block."""

    block: Mapping[str, Any]
    per_sample_mm: tuple[float, ...] | None

    @property
    def summary(self) -> str:
        """What was found, in words: the block's own ``summary``, else (a result of the day
        drift came in, before the summary was stored) worded now the same way."""
        text = self.block.get("summary")
        if isinstance(text, str):
            return text
        from calib.identify.result_json import drift_summary

        return drift_summary(self.block)


#: Length figures per model (``before``, ``after``) and part (``train``, ``test``):
#: ``n``, ``rmse_mm``, ``mae_mm``, ``std_mm``, ``max_mm`` (:func:`calib.accuracy.length_metrics`).
Metrics = Mapping[str, Mapping[str, Mapping[str, float | int | None]]]


def metrics_block(value: Any) -> Metrics:
    if not isinstance(value, Mapping):
        raise ResultError("metrics", f"must be an object, got {value!r}")
    for stage, parts in value.items():
        if not isinstance(parts, Mapping):
            raise ResultError(f"metrics.{stage}", "must be an object of parts")
        for part, figures in parts.items():
            if not isinstance(figures, Mapping):
                raise ResultError(f"metrics.{stage}.{part}", "must be an object of figures")
            for key, v in figures.items():
                if v is not None:
                    number(v, f"metrics.{stage}.{part}.{key}")
    return value


def dh_block(doc: Mapping[str, Any], key: str) -> tuple[DhRow, ...] | None:
    value = doc.get(key)
    if value is None:
        return None
    return tuple(DhRow.from_json(r, i, key) for i, r in enumerate(as_list(value, key)))


def named_numbers(value: Any, name: str) -> Mapping[str, float]:
    if value is None:
        return {}
    if not isinstance(value, Mapping):
        raise ResultError(name, f"must be an object, got {value!r}")
    return {str(k): number(v, f"{name}.{k}") for k, v in value.items()}


def anchors_block(value: Any) -> Mapping[str, AnchorFit]:
    if value is None:
        return {}
    if not isinstance(value, Mapping):
        raise ResultError("anchors", f"must be an object of anchors by id, got {value!r}")
    out: dict[str, AnchorFit] = {}
    for aid, fit in value.items():
        where = f"anchors.{aid}"
        if not isinstance(fit, Mapping):
            raise ResultError(where, f"must be an object, got {fit!r}")
        out[str(aid)] = AnchorFit(
            point(fit.get("anchor_mm"), f"{where}.anchor_mm"),
            number(fit.get("length_offset_mm"), f"{where}.length_offset_mm"),
        )
    return out


def notes_list(value: Any) -> tuple[str, ...]:
    if value is None:
        return ()
    notes = as_list(value, "notes")
    for i, n in enumerate(notes):
        if not isinstance(n, str):
            raise ResultError(f"notes[{i}]", f"must be text, got {n!r}")
    return tuple(notes)


def prior_block(doc: Mapping[str, Any]) -> Prior | None:
    block = opt_map(doc, "prior", "prior")
    if block is None:
        return None
    return Prior(
        used=opt_bool(block, "used", "prior.used"),
        noise_mm=opt_number(block, "noise_mm", "prior.noise_mm"),
        block=block,
    )


def drift_block(doc: Mapping[str, Any]) -> Drift | None:
    block = opt_map(doc, "drift", "drift")
    if not block:
        return None
    per = block.get("per_sample_mm")
    return Drift(block, None if per is None else numbers(per, "drift.per_sample_mm"))
