"""The calibration result: the one typed reader of ``result.json``.

:meth:`calib.identify.result_json.IdentifyResult.to_json` writes the document;
:class:`CalibrationResult` is the only code that reads it. It loads a parsed document
(:meth:`CalibrationResult.from_json`), checks the type of every field it knows (a
:class:`ResultError` names the field), says which shape of the contract wrote it
(:data:`RESULT_SHAPES`, :attr:`CalibrationResult.shape`) and keeps the document as
written, so :meth:`CalibrationResult.to_json` gives back the same JSON, byte for byte, with
the keys it does not know.

Every field a release added after the first contract is optional here, and so is every other
field: the HTML report renders a partial result and says what is missing, and a daemon keeps
results written by earlier releases for years (``tests/data/result_shape*.json`` hold one file
of each shape). A caller that needs a field asks for it (:meth:`CalibrationResult.dh_rows`,
:meth:`CalibrationResult.anchor_fit`, ...) and gets a :class:`ResultError` naming it when it
is absent. Standard library only: the CLI's commands load results cheaply.

Units as in the document: lengths in mm, angles in degrees.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

from calib.result_fields import (
    DH_KEYS,
    AnchorFit,
    Correlation,
    DhRow,
    Drift,
    Metrics,
    Prior,
    ResultError,
    Split,
    anchors_block,
    dh_block,
    drift_block,
    integers,
    metrics_block,
    named_numbers,
    notes_list,
    numbers,
    opt_bool,
    opt_int,
    opt_map,
    opt_number,
    opt_str,
    point,
    prior_block,
)
from calib.sample_fields import DEFAULT_ANCHOR

__all__ = [
    "DH_KEYS",
    "RESULT_KEYS",
    "RESULT_SHAPES",
    "AnchorFit",
    "CalibrationResult",
    "Correlation",
    "DhRow",
    "Drift",
    "Metrics",
    "Prior",
    "ResultError",
    "ResultLike",
    "ResultShape",
    "Split",
    "shape_of",
]

Convention = Literal["dh", "mdh"]

#: The keys of the first contract (2026-11-21, commit aabb0f2, ``calib/identify.py``).
BASE_KEYS = (
    "robot",
    "method",
    "convention",
    "dh",
    "dh_error",
    "tool_mm",
    "anchor_mm",
    "length_offset_mm",
    "anchor_id",
    "anchors",
    "uncertainty",
    "correlation",
    "identifiability",
    "metrics",
    "flagged_samples",
    "iterations",
    "elapsed_s",
    "status",
    "success",
    "message",
    "cost_history_rms_mm",
    "prior",
    "robust",
    "split",
    "plausibility",
    "notes",
)


@dataclass(frozen=True)
class ResultShape:
    """One shape of ``result.json``: the keys it added to the one before, and since when."""

    number: int
    since: str
    added: tuple[str, ...]


#: Every shape identify has written, oldest first (found in ``git log -p`` of
#: ``calib/identify.py`` and ``calib/report.py``). A document of shape ``n`` holds the keys of
#: every shape up to ``n``. ``controller`` (2026-11-28, caf347f) marks no shape: it is written
#: only for a robot whose controller does not count its joints as the table. The daemon adds
#: ``flagged_sample_ids``, ``split.test_sample_ids`` and ``plan_check`` to what it stores.
RESULT_SHAPES = (
    ResultShape(1, "2026-11-21 (aabb0f2): the first contract", BASE_KEYS),
    ResultShape(2, "2026-11-23 (3858223): the tool point's 1σ", ("tcp_uncertainty_mm",)),
    ResultShape(3, "2026-11-23 (c58351c): the robust step's detail", ("robust_detail",)),
    ResultShape(
        4,
        "2026-11-25 (148991a): the measurement's drift, the fits' starts, split.test_rows",
        ("cost_history_fit_starts", "drift"),
    ),
)

#: Every top-level key the result may hold (identify's and the daemon's).
RESULT_KEYS = frozenset(
    {k for s in RESULT_SHAPES for k in s.added} | {"controller", "flagged_sample_ids", "plan_check"}
)


# --------------------------------------------------------------------------------- result
@dataclass(frozen=True)
class CalibrationResult:
    """A loaded ``result.json``; every field as the document wrote it, None (or empty) when
    the document does not hold it. Build with :meth:`from_json` or :meth:`of`."""

    robot: str | None
    method: str | None
    convention: Convention | None
    dh: tuple[DhRow, ...] | None
    dh_error: tuple[DhRow, ...] | None
    tool_mm: tuple[float, float, float] | None
    anchor_id: str | None
    anchor_mm: tuple[float, float, float] | None
    length_offset_mm: float | None
    #: The anchors after the first, by id.
    anchors: Mapping[str, AnchorFit]
    #: 1σ of every solved parameter by name, in display units (deg, mm).
    uncertainty: Mapping[str, float]
    #: Predicted 1σ tool-point error ``{"rms", "max"}`` [mm] (shape 2).
    tcp_uncertainty_mm: Mapping[str, float] | None
    correlation: Correlation | None
    identifiability: Mapping[str, Any] | None
    metrics: Metrics | None
    flagged_samples: tuple[int, ...]
    iterations: int | None
    elapsed_s: float | None
    status: int | None
    success: bool | None
    message: str | None
    cost_history_rms_mm: tuple[float, ...] | None
    cost_history_fit_starts: tuple[int, ...] | None
    prior: Prior | None
    robust: str | None
    robust_detail: Mapping[str, Any] | None
    drift: Drift | None
    split: Split | None
    plausibility: Mapping[str, Any] | None
    notes: tuple[str, ...]
    #: How the controller counts its joints against the table (:mod:`calib.conventions`).
    controller: Mapping[str, Any] | None
    #: The daemon's: the flagged rows' sample ids, and whether the samples followed the plan.
    flagged_sample_ids: tuple[int, ...] | None
    plan_check: Mapping[str, Any] | None
    #: The shape of the contract the document has (:data:`RESULT_SHAPES`); 0: a partial one.
    shape: int
    _doc: Mapping[str, Any] = field(repr=False, compare=False)

    # ------------------------------------------------------------------------ loading
    @classmethod
    def of(cls, result: CalibrationResult | Mapping[str, Any]) -> CalibrationResult:
        """``result`` itself when it is loaded already, else :meth:`from_json`."""
        return result if isinstance(result, CalibrationResult) else cls.from_json(result)

    @classmethod
    def from_json(cls, doc: Mapping[str, Any]) -> CalibrationResult:
        """Load a parsed ``result.json`` of any shape. The document is kept as given (not
        copied): the caller does not change it afterwards; :meth:`to_json` gives a copy.

        Raises
        ------
        TypeError
            ``doc`` is not a mapping.
        ResultError
            A field of the wrong type (named).
        """
        if not isinstance(doc, Mapping):
            raise TypeError(f"result: expected a mapping (parsed result.json), got {type(doc)}")
        convention = opt_str(doc, "convention", "convention")
        if convention not in (None, "dh", "mdh"):
            raise ResultError("convention", f"must be 'dh' or 'mdh', got {convention!r}")
        return cls(
            robot=opt_str(doc, "robot", "robot"),
            method=opt_str(doc, "method", "method"),
            convention=convention,  # type: ignore[arg-type]  # checked above
            dh=dh_block(doc, "dh"),
            dh_error=dh_block(doc, "dh_error"),
            tool_mm=None if doc.get("tool_mm") is None else point(doc["tool_mm"], "tool_mm"),
            anchor_id=opt_str(doc, "anchor_id", "anchor_id"),
            anchor_mm=None
            if doc.get("anchor_mm") is None
            else point(doc["anchor_mm"], "anchor_mm"),
            length_offset_mm=opt_number(doc, "length_offset_mm", "length_offset_mm"),
            anchors=anchors_block(doc.get("anchors")),
            uncertainty=named_numbers(doc.get("uncertainty"), "uncertainty"),
            tcp_uncertainty_mm=None
            if doc.get("tcp_uncertainty_mm") is None
            else named_numbers(doc["tcp_uncertainty_mm"], "tcp_uncertainty_mm"),
            correlation=None
            if (corr := opt_map(doc, "correlation", "correlation")) is None
            else Correlation.from_json(corr),
            identifiability=opt_map(doc, "identifiability", "identifiability"),
            metrics=None if doc.get("metrics") is None else metrics_block(doc["metrics"]),
            flagged_samples=integers(doc.get("flagged_samples") or [], "flagged_samples"),
            iterations=opt_int(doc, "iterations", "iterations"),
            elapsed_s=opt_number(doc, "elapsed_s", "elapsed_s"),
            status=opt_int(doc, "status", "status"),
            success=opt_bool(doc, "success", "success"),
            message=opt_str(doc, "message", "message"),
            cost_history_rms_mm=None
            if doc.get("cost_history_rms_mm") is None
            else numbers(doc["cost_history_rms_mm"], "cost_history_rms_mm"),
            cost_history_fit_starts=None
            if doc.get("cost_history_fit_starts") is None
            else integers(doc["cost_history_fit_starts"], "cost_history_fit_starts"),
            prior=prior_block(doc),
            robust=opt_str(doc, "robust", "robust"),
            robust_detail=opt_map(doc, "robust_detail", "robust_detail"),
            drift=drift_block(doc),
            split=None if (sp := opt_map(doc, "split", "split")) is None else Split.from_json(sp),
            plausibility=opt_map(doc, "plausibility", "plausibility"),
            notes=notes_list(doc.get("notes")),
            controller=opt_map(doc, "controller", "controller"),
            flagged_sample_ids=None
            if doc.get("flagged_sample_ids") is None
            else integers(doc["flagged_sample_ids"], "flagged_sample_ids"),
            plan_check=opt_map(doc, "plan_check", "plan_check"),
            shape=shape_of(doc),
            _doc=doc,
        )

    def to_json(self) -> dict[str, Any]:
        """The document as it was loaded (a copy): the same JSON, key for key."""
        return copy.deepcopy(dict(self._doc))

    # ------------------------------------------------------------------------- needed
    def dh_rows(self) -> tuple[DhRow, ...]:
        """The calibrated DH table's six rows.

        Raises
        ------
        ResultError
            ``dh`` is missing or has not six joints.
        """
        if self.dh is None or len(self.dh) != 6:
            raise ResultError("dh", "expected a list of six joint rows")
        return self.dh

    def tool(self) -> tuple[float, float, float]:
        """The calibrated tool point (x, y, z) [mm, flange frame]; ResultError when absent."""
        if self.tool_mm is None:
            raise ResultError("tool_mm", "missing")
        return self.tool_mm

    @property
    def first_anchor(self) -> str:
        """The id of the anchor ``anchor_mm`` belongs to."""
        return self.anchor_id if self.anchor_id is not None else DEFAULT_ANCHOR

    def anchor_ids(self) -> list[str]:
        """Every anchor's id, the first one first."""
        return [self.first_anchor, *self.anchors]

    def anchor_fit(self, anchor: str | None = None) -> AnchorFit:
        """The fit of ``anchor`` (default the first).

        Raises
        ------
        ResultError
            The first anchor's fields are missing, or the result does not hold ``anchor``.
        """
        if anchor is None or anchor == self.first_anchor:
            if self.anchor_mm is None:
                raise ResultError("anchor_mm", "missing")
            if self.length_offset_mm is None:
                raise ResultError("length_offset_mm", "missing")
            return AnchorFit(self.anchor_mm, self.length_offset_mm)
        if anchor not in self.anchors:
            raise ResultError("anchor", f"{anchor!r} is not in the result ({self.anchor_ids()})")
        return self.anchors[anchor]

    def anchor_fits(self) -> dict[str, AnchorFit]:
        """Every anchor's fit by id, the first one first."""
        return {a: self.anchor_fit(a) for a in self.anchor_ids()}

    def figures(self, stage: str, part: str) -> Mapping[str, float | int | None]:
        """The length figures of model ``stage`` (``before``, ``after``) on ``part`` (``train``,
        ``test``); empty when the result holds none."""
        return ((self.metrics or {}).get(stage) or {}).get(part) or {}

    @property
    def plausible(self) -> bool:
        """Whether every identified parameter lies within its plausible bound."""
        return bool((self.plausibility or {}).get("plausible", False))

    def with_theta_shift(self, joint: int, delta_deg: float) -> CalibrationResult:
        """This result with row ``joint`` (0-based) of ``dh`` turned by ``delta_deg`` [deg]
        (its ``theta_deg``; the document too)."""
        doc = self.to_json()
        row = doc["dh"][joint]
        row["theta_deg"] = float(row["theta_deg"]) + delta_deg
        return CalibrationResult.from_json(doc)

    # ----------------------------------------------------------------------- the daemon's
    def with_sample_ids(self, sample_ids: Sequence[int]) -> dict[str, Any]:
        """The document with the sample ids of the flagged rows (``flagged_sample_ids``) and
        of the test rows (``split.test_sample_ids``); ``sample_ids[i]`` is row ``i``'s id."""
        out = self.to_json()
        out["flagged_sample_ids"] = [sample_ids[i] for i in self.flagged_samples]
        if isinstance(out.get("split"), dict):
            rows = (self.split.test_rows if self.split else None) or ()
            out["split"]["test_sample_ids"] = [sample_ids[i] for i in rows]
        return out

    def with_plan_check(self, check: Mapping[str, Any], note: str | None) -> dict[str, Any]:
        """The document with the daemon's ``plan_check`` and, when given, its ``note`` last
        among the ``notes``."""
        out = self.to_json()
        out["plan_check"] = dict(check)
        if note is not None:
            out.setdefault("notes", []).append(note)
        return out


#: A loaded result, or a parsed ``result.json`` (a function taking it loads it on entry:
#: :meth:`CalibrationResult.of`).
ResultLike = CalibrationResult | Mapping[str, Any]


def shape_of(doc: Mapping[str, Any]) -> int:
    """The newest shape of :data:`RESULT_SHAPES` whose keys ``doc`` holds, with every older
    shape's; 0 when it lacks a key of the first (a partial document)."""
    found = 0
    for shape in RESULT_SHAPES:
        if not all(k in doc for k in shape.added):
            break
        found = shape.number
    return found
