"""The dialect interface of ``cablecal filter``: sources, target sites, uses, edits.

A **dialect** (the ``filter`` module of each language, ``calib.programs.<language>.filter``) turns
of the files given to the filter into :class:`Target` sites and writes corrected numbers
back. It never rewrites a file: it returns :class:`Edit` s, each replacing exactly the
characters of one number, and :func:`apply_edits` splices them in. Every other character
(comments, whitespace, line endings, the rest of the program) is kept, and
:class:`Source` re-encodes the text with the file's own encoding, so every byte outside the
edited numbers is unchanged.

The flow (:mod:`calib.filter.run`):

1. :meth:`Dialect.parse` reads all files of its dialect at once (a RAPID task's tool data may
   sit in another module; a KRL ``.src`` needs its ``.dat`` and ``$config.dat``) and returns
   one :class:`Target` per target site: a declaration (or one element of an array
   declaration), or an inline target inside a move. Each carries its pose (Cartesian: a
   4x4 frame in its work object, mm) or joints (deg), how the controller picks the IK
   branch (:class:`Configuration`), and its :class:`Use` s: every move that uses it, with
   the tool and work object resolved to frames (or the reason they could not be).
2. The core (:mod:`calib.filter.correct`) corrects every target whose uses agree on one
   tool and one work object and returns a :class:`~calib.filter.correct.Correction`.
3. :meth:`Dialect.render` turns a correction into edits of the target's numbers, written
   with :func:`format_number`: at the precision the controller keeps, and a number whose
   corrected value equals the original at that precision keeps its original text, so a
   filter with the calibration equal to the nominal model changes no byte.

Frames: ``tool`` is the TCP frame in the flange frame, ``work`` the work object in the robot's
base frame; a Cartesian target ``T`` (in ``work``, of ``tool``) asks the flange to be at
``work · T · tool⁻¹``. All 4x4, translation in mm.
"""

from __future__ import annotations

import bisect
import math
import re
from array import array
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any, Literal, NamedTuple, Protocol

import numpy as np

from calib.kinematics import N_JOINTS, FloatArray
from calib.programs.inputs import FilterInputError as FilterInputError
from calib.programs.inputs import FrameTables as FrameTables
from calib.programs.inputs import parse_frames_toml as parse_frames_toml
from calib.programs.lexer import split_top

Kind = Literal["cartesian", "joint"]
#: What became of a target: corrected (possibly by less than the written precision, then no
#: byte changes), unreachable (no calibrated solution on the branch, or outside the joint
#: limits), or skipped (with the reason: frame not resolved, used with two tools, ...).
Status = Literal["corrected", "unreachable", "skipped"]

#: The reason of a target that no move of the given files uses (a point a data file declares
#: for programs not given), or its start (a dialect may add ": " and a detail). Reported,
#: never counted as left: it alone never makes exit 3 (:mod:`calib.filter.run`).
UNUSED_REASON = "not used by any move in the given files"
#: The reason (or its start) of a target in a file the filter reads and never writes (KUKA's
#: ``$config.dat``): left on purpose, never counted as left.
READ_ONLY_REASON = "in a file that is read and never written"

#: The reason (or its start) of a target that carries a value for an external axis (a track,
#: a positioner), which the model does not have. A model whose ``[controller]`` table says
#: ``external_axes = 0`` (the controller drives none, so it ignores such values) has these
#: targets corrected with the values carried unchanged (:mod:`calib.filter.run`).
EXTERNAL_AXIS_REASON = "carries external axis values"
#: What the reason adds: how to say the robot has none.
EXTERNAL_AXIS_ADVICE = (
    "the model has no external axes: if this controller drives none (no track, no "
    "positioner), say so with external_axes = 0 in the model file's [controller] table"
)

#: Within this of joint 5 = 0 (the controller's angle) the wrist is at its singularity [deg]
#: (the wrist sign of :class:`Configuration` is noise there): KUKA's joint targets closer are
#: left as singular, and compensate counts a wrist flip only when both sides are further.
WRIST_SINGULARITY_DEG = 1.0
#: How every dialect names a target left at the wrist singularity (the start of its reason;
#: the engine adds joint 5 and what the correction would turn, KUKA's joint targets "(A5 = 0)").
WRIST_SINGULARITY_REASON = "wrist singularity"

#: Largest rounding a written number may cost: position [mm] and orientation [deg].
POSITION_ROUNDING_MM = 0.001
ORIENTATION_ROUNDING_DEG = 0.0005


@dataclass(frozen=True)
class Source:
    """One input file, decoded losslessly.

    Attributes
    ----------
    name : str
        The file's name as given (used in messages and the summary).
    text : str
        Decoded text; line ends are kept as they are (``\\r\\n`` stays ``\\r\\n``).
    encoding : {"utf-8", "latin-1"}
        UTF-8 when the bytes are valid UTF-8 (a BOM stays in ``text`` as ``\\ufeff``), else
        Latin-1, which maps every byte to one character and back.
    """

    name: str
    text: str
    encoding: str

    @classmethod
    def from_bytes(cls, name: str, data: bytes) -> Source:
        try:
            return cls(name, data.decode("utf-8"), "utf-8")
        except UnicodeDecodeError:
            return cls(name, data.decode("latin-1"), "latin-1")

    def encode(self, text: str | None = None) -> bytes:
        """``text`` (default: the original) in the file's encoding.

        Raises
        ------
        FilterInputError
            The text holds a character the encoding cannot carry (never for edits made
            of digits, signs and points).
        """
        try:
            return (self.text if text is None else text).encode(self.encoding)
        except UnicodeEncodeError as exc:
            raise FilterInputError(self.name, f"cannot encode as {self.encoding}: {exc}") from None

    @cached_property
    def _line_starts(self) -> array[int]:
        """Offsets where lines start (a compact array: a long program has many lines)."""
        return array("q", (m.end() for m in re.finditer("\n", self.text)))

    def line_of(self, offset: int) -> int:
        """1-based line number of a character offset."""
        return bisect.bisect_right(self._line_starts, offset) + 1


class Num(NamedTuple):
    """One number of a target as it stands in its file.

    ``start, end`` are character offsets into :attr:`Source.text`; ``text`` the original
    characters; ``value`` what they mean (as the controller reads them). A named tuple: the
    cyclic garbage collector keeps tracking it (it stops tracking exact tuples of atoms
    only), so a long program's numbers cost collection time while they live;
    :func:`calib.filter.run.filter_files` lets go of them batch by batch.
    """

    file: str
    start: int
    end: int
    text: str
    value: float


class Edit(NamedTuple):
    """Replace ``text[start:end]`` of ``file`` by ``new`` (a tuple: a program has one per
    rewritten number)."""

    file: str
    start: int
    end: int
    new: str


#: An :class:`Edit` kept as an exact tuple ``(file, start, end, new)`` (``tuple(edit)``): the
#: cyclic garbage collector stops tracking an exact tuple of atoms, never a named tuple, so a
#: filter run keeps its hundreds of thousands of edits in this form.
EditTuple = tuple[str, int, int, str]


@dataclass(frozen=True, slots=True)
class Use:
    """One move that uses a target, with its tool and work object.

    Attributes
    ----------
    file : str
    line : int
        1-based line of the move.
    tool_name, work_name : str
        As the program names them (``tool0``, ``UT:2``, ``set_tcp@12`` …).
    tool : ndarray, shape (4, 4), or None
        TCP in the flange frame [mm]; None when it cannot be resolved (``problem`` says why).
    work : ndarray, shape (4, 4), or None
        Work object / user frame in the base frame [mm]; None when unresolved.
    problem : str
        Why the tool or work object could not be resolved; empty when both are.
    """

    file: str
    line: int
    tool_name: str
    work_name: str
    tool: FloatArray | None
    work: FloatArray | None
    problem: str = ""

    @property
    def key(self) -> tuple[str, str]:
        return (self.tool_name, self.work_name)


#: A :class:`Configuration`'s joint ranges where the program says nothing: every joint open
#: (one read-only array that every such configuration shares).
OPEN_RANGES_DEG: FloatArray = np.tile([-np.inf, np.inf], (N_JOINTS, 1))
OPEN_RANGES_DEG.flags.writeable = False


@dataclass(frozen=True, slots=True)
class Configuration:
    """How the controller picks the IK branch of a Cartesian target, in dialect-neutral form.

    Attributes
    ----------
    joint_ranges_deg : ndarray, shape (6, 2)
        Per joint the half-open interval ``[lo, hi)`` the nominal solution must lie in
        (RAPID ``cf1/cf4/cf6`` quadrants, KUKA ``T`` signs, Fanuc turn numbers); ``±inf``
        where the program says nothing.
    shoulder, elbow, wrist : {+1, -1} or None
        Branch signs, None where the program says nothing (computed by
        :func:`calib.filter.branches.branch_signs` on the nominal model; ``c`` is the wrist
        centre, ``o_k`` a point on axis ``k``, ``x_1`` the x axis of frame 1, ``z`` the base
        z axis and ``h`` the horizontal unit vector from axis 1 towards ``c``):

        * ``shoulder`` +1 (front) when ``(c − o_1) · x_1 > 0``, else −1 (behind axis 1);
        * ``elbow`` +1 (up) when axis 3 lies above the line from axis 2 to the wrist centre,
          ``(z × h) · ((c − o_2) × (o_3 − o_2)) < 0``, else −1 (down);
        * ``wrist`` +1 when joint 5 (the controller's angle) is ≥ 0, else −1.

        A dialect maps its own flags to these (RAPID ``cfx``, KUKA ``S``, Fanuc ``N/F U/D
        T/B``). They only break ties: the joint ranges (quadrants, signs, turns) decide
        first, and the only solution within the joint limits is taken whatever they say.
    nearest_deg : ndarray, shape (6,), or None
        Take the solution nearest these joints (UR: the waypoint's ``q``).
    after : str or None
        Take the solution nearest the nominal joints of this other target of the same file
        (UR without a ``q``: the previous move's target).
    text : str
        The configuration as the program writes it, for messages.
    ranges_rewritten : bool
        True where the dialect writes the corrected joints' ranges back (no dialect does
        now). Else a correction that leaves ``joint_ranges_deg`` (an ABB quadrant, read with
        its edge tolerance; a KUKA ``T`` sign; a Fanuc turn number) is refused with the
        reason: those fields are never rewritten.
    honoured : bool
        False where the controller ignores the written configuration and takes the solution
        nearest where the robot is, which the program does not say (ABB's first move under
        ``ConfL\\Off``/``ConfJ\\Off``): the written ranges and signs are taken when they fit a
        solution, and the only solution within the joint limits whatever they say.
    """

    joint_ranges_deg: FloatArray = field(default_factory=lambda: OPEN_RANGES_DEG)
    shoulder: int | None = None
    elbow: int | None = None
    wrist: int | None = None
    nearest_deg: FloatArray | None = None
    after: str | None = None
    text: str = ""
    ranges_rewritten: bool = False
    honoured: bool = True


@dataclass(slots=True)
class Target:
    """One target site of a program.

    Attributes
    ----------
    file : str
    line : int
        1-based line where the target's value starts.
    name : str
        Declared name (``p10``, ``p10{3}``, ``XP4``, ``P[7]``) or ``inline@<line>``.
    kind : {"cartesian", "joint"}
    pose : ndarray, shape (4, 4), or None
        Cartesian targets: the target in its work object [mm].
    joints_deg : ndarray, shape (6,), or None
        Joint targets [deg] (the controller's joint angles).
    configuration : Configuration or None
        Cartesian targets: how the controller picks the branch.
    uses : list of Use
        Every move using the target, in program order.
    problem : str
        The dialect's reason not to correct this target (e.g. a stationary tool); empty
        otherwise.
    follows : str or None
        A joint target that must become the corrected joints of another (Cartesian) target
        of the same file (a PolyScope ``Waypoint_n_q`` follows ``Waypoint_n_p``): its name.
    site : Any
        The dialect's own data about where the numbers are (only :meth:`Dialect.render`
        reads it). :func:`calib.filter.run.filter_files` lets go of it (None) once the
        target's batch is written: the edits hold the numbers the summary shows.
    """

    file: str
    line: int
    name: str
    kind: Kind
    pose: FloatArray | None = None
    joints_deg: FloatArray | None = None
    configuration: Configuration | None = None
    uses: list[Use] = field(default_factory=list)
    problem: str = ""
    follows: str | None = None
    site: Any = None


@dataclass(frozen=True, slots=True)
class Correction:
    """What the core found for one target.

    Attributes
    ----------
    status : {"corrected", "unreachable", "skipped"}
    reason : str
        Why a target was not corrected (empty when it was).
    pose : ndarray, shape (4, 4), or None
        Cartesian targets: the corrected target ``T′`` in its work object [mm].
    joints_deg : ndarray, shape (6,), or None
        Joint targets: the corrected joints ``q′``; Cartesian targets: ``q*``, the joints the
        nominal controller will reach ``T′`` at (its quadrant/turn fields follow them).
    nominal_joints_deg : ndarray, shape (6,), or None
        The nominal solution of the original target on the controller's branch.
    shift_mm, shift_deg : float
        How far the target moved (TCP position [mm], orientation [deg]); NaN when not
        corrected.
    configuration_kept : bool or None
        The corrected joints lie on the same branch (shoulder, elbow, wrist) as the nominal
        solution (quadrant/turn numbers may change; they follow the joints).
    sigma_mm : float
        Predicted 1σ position error at the target's own tool point from the result's
        covariance [mm]; NaN when the result carries none.
    """

    status: Status
    reason: str = ""
    pose: FloatArray | None = None
    joints_deg: FloatArray | None = None
    nominal_joints_deg: FloatArray | None = None
    shift_mm: float = math.nan
    shift_deg: float = math.nan
    configuration_kept: bool | None = None
    sigma_mm: float = math.nan


class Dialect(Protocol):
    """What a controller language module provides (see the module docstring).

    Attributes
    ----------
    name : str
        ``rapid``, ``krl``, ``urscript``, ``fanuc-ls``.
    extensions : tuple of str
        Lower-case file extensions with the dot (``.mod``); ``claims`` decides among them.
    """

    name: str
    extensions: tuple[str, ...]

    def claims(self, source: Source) -> bool:
        """Whether this file is of the dialect (extension and content)."""
        ...

    def parse(self, sources: Sequence[Source], frames: FrameTables) -> list[Target]:
        """All targets of the dialect's files (given together).

        Raises
        ------
        FilterInputError
            A file that cannot be read, naming the file and line.
        """
        ...

    def render(self, target: Target, correction: Correction) -> list[Edit]:
        """Edits writing a corrected target's numbers (and its quadrant/turn fields)."""
        ...


def decimals_of(text: str) -> int:
    """Decimals written in a number's text (``"12.50"`` → 2, ``"7"`` → 0, ``"1E+3"`` → 0)."""
    dot = text.find(".")
    if dot < 0:
        return 0
    frac = text[dot + 1 :].rstrip()
    exp = frac.find("e") if "e" in frac else frac.find("E")
    return len(frac) if exp < 0 else exp


#: Half a unit of the last written decimal, by decimals.
_HALF_UNIT = tuple(0.5 * 10.0**-d for d in range(40))


def format_number(original: Num, value: float, min_decimals: int) -> str:
    """``value`` written like ``original``: with ``max(its decimals, min_decimals)`` decimals
    (fixed point). When ``value`` equals the original at that precision (or to floating-point
    round-off), the original text is returned unchanged (so a filter that moves nothing
    changes no byte)."""
    otext = original.text
    dec = decimals_of(otext)
    if dec < min_decimals:
        dec = min_decimals
    # Equal at the written precision, or up to floating-point round-off (a PolyScope joint
    # written with 16 decimals, converted to degrees and back).
    diff = abs(value - original.value)
    half = _HALF_UNIT[dec] if dec < 40 else 0.5 * 10.0**-dec
    if diff < half or diff < 1e-12 * max(1.0, abs(value)):
        return otext
    text = f"{value:.{dec}f}"
    first = otext[0]
    if text[0] == "-" and float(text) == 0.0:
        text = text[1:]
    if first == "+" and text[0] != "-":
        text = "+" + text
    if dec and first in ".+-" and (first == "." or otext[1:2] == "."):
        sign = "-" if text[0] == "-" else ""
        body = text.lstrip("+-")
        if body.startswith("0."):
            text = ("+" if text[0] == "+" else sign) + body[1:]  # keep a style like ".25"
    return text


def edit(original: Num, value: float, min_decimals: int) -> Edit | None:
    """The edit writing ``value`` over ``original`` (None when the text stays)."""
    new = format_number(original, value, min_decimals)
    if new == original.text:
        return None
    return Edit(original.file, original.start, original.end, new)


def edits_for(nums: Sequence[Num], values: Iterable[float], min_decimals: int) -> list[Edit]:
    """The edits writing ``values`` over ``nums`` in order, each with at least
    ``min_decimals``; a number whose text stays is left out (:func:`edit`)."""
    out = []
    for num, value in zip(nums, values, strict=True):
        new = format_number(num, float(value), min_decimals)
        if new != num.text:
            out.append(Edit(num.file, num.start, num.end, new))
    return out


def apply_edits(text: str, edits: Sequence[EditTuple]) -> str:
    """``text`` with the edits (:class:`Edit` or :data:`EditTuple`) spliced in (edits of one
    file, non-overlapping).

    Raises
    ------
    ValueError
        Overlapping edits (a dialect bug).
    """
    out: list[str] = []
    pos = 0
    for _file, start, end, new in sorted(edits, key=lambda e: e[1]):
        if start < pos:
            raise ValueError(f"overlapping edits at offset {start}")
        out.append(text[pos:start])
        out.append(new)
        pos = end
    out.append(text[pos:])
    return "".join(out)


#: Comma-separated arguments at bracket depth 0, as spans: the shared lexer's
#: :func:`~calib.programs.lexer.split_top` (a RAPID argument list, a URScript list or call).
split_args = split_top
