"""How a robot's controller counts its joints against the kinematic (DH) table.

Every joint angle the project stores, reads from a controller or writes into a program is the
controller's own (what its pendant shows). The kinematic table works on *table angles*::

    q_table[j] = direction[j] * q_ctrl[j] + sum over couplings (j, k, f) of f * q_ctrl[k]

and the table's ``theta_deg`` is then added as before, so the zero of each joint is the table's
``theta_deg`` (one home). ``direction`` is +1 where the controller's positive sense is the
table's (a right-handed turn about the joint's z axis), -1 where it is opposite; a coupling
adds another joint's controller angle, e.g. Fanuc's J2/J3 interaction: the pendant's J3 is the
forearm's angle from the horizontal, so the table's elbow angle is J3 + J2 (with the signs of
the arm's model file). The identity (all +1, no coupling) is what model files without a
``[controller]`` table mean, so old files keep their meaning.

File format (in a model file)::

    [controller]
    maker = "fanuc"                         # abb, kuka, fanuc, ur or other (optional)
    direction = [1, 1, -1, 1, -1, 1]        # per joint, +1 or -1
    couplings = [{joint = 3, from = 2, factor = 1.0}]   # joints numbered 1..6 as the pendant
    external_axes = 0                       # optional: the controller has no external axes

``external_axes = 0`` says the controller drives no axis besides the arm's six (no track, no
positioner). ABB's controller then ignores a value written for an external axis ("If the
position is defined in the position data, although the axis is not connected, the value will
be ignored", RAPID reference, extjoint), so the filter corrects such targets and carries the
values unchanged; without it they are left with that reason (docs/robots.md). A count above 0
says the axes exist: they are not modelled, and targets using them are left.

Shapes: joint arrays are (6,) or (n, 6), angles in degrees.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal, get_args

import numpy as np
from numpy.typing import NDArray

N_JOINTS = 6
#: External axes a controller's target can carry (ABB's eax_a … eax_f).
MAX_EXTERNAL_AXES = 6
Maker = Literal["abb", "kuka", "fanuc", "ur", "other"]
MAKERS: tuple[str, ...] = get_args(Maker)


class ConventionError(ValueError):
    """An invalid ``[controller]`` table; ``field`` names the entry."""

    def __init__(self, field_name: str, message: str) -> None:
        super().__init__(f"{field_name}: {message}")
        self.field = field_name
        self.message = message


@dataclass(frozen=True)
class JointConvention:
    """The controller's joint directions and couplings (see the module docstring).

    Attributes
    ----------
    maker : str or None
        ``abb``, ``kuka``, ``fanuc``, ``ur``, ``other``; None when not said.
    direction : tuple of 6 int
        +1 or -1 per joint.
    couplings : tuple of (joint, from_joint, factor)
        0-based joint indices; ``q_table[joint] += factor * q_ctrl[from_joint]``.
    external_axes : int or None
        How many external axes the controller drives (0: none); None when not said.
    """

    maker: str | None = None
    direction: tuple[int, ...] = (1, 1, 1, 1, 1, 1)
    couplings: tuple[tuple[int, int, float], ...] = ()
    external_axes: int | None = None

    @property
    def is_identity(self) -> bool:
        """True when the controller's angles are the table's."""
        return all(d == 1 for d in self.direction) and not self.couplings

    def matrix(self) -> NDArray[np.float64]:
        """``M`` (6, 6) with ``q_table = M @ q_ctrl``."""
        m = np.diag(np.asarray(self.direction, dtype=float))
        for j, k, f in self.couplings:
            m[j, k] += f
        return m

    def to_table_deg(self, q_ctrl_deg: NDArray[np.float64]) -> NDArray[np.float64]:
        """Table angles [deg] of controller angles [deg], shape (6,) or (n, 6) kept."""
        q = np.asarray(q_ctrl_deg, dtype=float)
        if self.is_identity:
            return q
        out: NDArray[np.float64] = q @ self.matrix().T
        return out

    def to_controller_deg(self, q_table_deg: NDArray[np.float64]) -> NDArray[np.float64]:
        """Controller angles [deg] of table angles [deg], shape (6,) or (n, 6) kept."""
        q = np.asarray(q_table_deg, dtype=float)
        if self.is_identity:
            return q
        out: NDArray[np.float64] = q @ np.linalg.inv(self.matrix()).T
        return out

    def to_dict(self) -> dict[str, Any]:
        """The ``[controller]`` table of a model file."""
        out: dict[str, Any] = {"direction": list(self.direction)}
        if self.maker is not None:
            out = {"maker": self.maker, **out}
        if self.couplings:
            out["couplings"] = [
                {"joint": j + 1, "from": k + 1, "factor": float(f)} for j, k, f in self.couplings
            ]
        if self.external_axes is not None:
            out["external_axes"] = self.external_axes
        return out


IDENTITY = JointConvention()


def controller_block(convention: JointConvention) -> dict[str, Any]:
    """``{"controller": …}`` for a model file or ``result.json``; empty for :data:`IDENTITY`
    (so files of robots whose controller counts as the table stay as they were)."""
    return {} if convention == IDENTITY else {"controller": convention.to_dict()}


def _number(value: Any, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not np.isfinite(value):
        raise ConventionError(where, f"must be a finite number, got {value!r}")
    return float(value)


def convention_from_mapping(data: Any) -> JointConvention:
    """Validate a ``[controller]`` table; errors name the field (``controller.direction[3]``)."""
    if data is None:
        return IDENTITY
    if not isinstance(data, Mapping):
        raise ConventionError("controller", "must be a table/object")
    known = {"maker", "direction", "couplings", "external_axes"}
    for key in data:
        if key not in known:
            raise ConventionError(f"controller.{key}", f"unknown field (expected {sorted(known)})")
    maker = data.get("maker")
    if maker is not None and maker not in MAKERS:
        raise ConventionError("controller.maker", f"must be one of {list(MAKERS)}, got {maker!r}")
    raw = data.get("direction", [1] * N_JOINTS)
    if not isinstance(raw, Sequence) or isinstance(raw, str) or len(raw) != N_JOINTS:
        raise ConventionError(
            "controller.direction", f"must be a list of 6 (+1 or -1), got {raw!r}"
        )
    direction = []
    for i, v in enumerate(raw):
        if isinstance(v, bool) or v not in (1, -1):
            raise ConventionError(f"controller.direction[{i + 1}]", f"must be 1 or -1, got {v!r}")
        direction.append(int(v))
    couplings = []
    raw_c = data.get("couplings", [])
    if not isinstance(raw_c, Sequence) or isinstance(raw_c, str):
        raise ConventionError("controller.couplings", "must be a list of tables")
    for i, c in enumerate(raw_c):
        where = f"controller.couplings[{i + 1}]"
        if not isinstance(c, Mapping) or set(c) - {"joint", "from", "factor"}:
            raise ConventionError(where, "must be a table of joint, from and factor")
        j, k = c.get("joint"), c.get("from")
        for name, v in (("joint", j), ("from", k)):
            if isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= N_JOINTS:
                raise ConventionError(f"{where}.{name}", f"must be a joint 1..6, got {v!r}")
        if j == k:
            raise ConventionError(f"{where}.from", "must be another joint")
        couplings.append((int(j) - 1, int(k) - 1, _number(c.get("factor", 1.0), f"{where}.factor")))  # type: ignore[arg-type]
    external = data.get("external_axes")
    if external is not None and (
        isinstance(external, bool)
        or not isinstance(external, int)
        or not 0 <= external <= MAX_EXTERNAL_AXES
    ):
        raise ConventionError(
            "controller.external_axes",
            f"must be a count 0..{MAX_EXTERNAL_AXES} (0: none), got {external!r}",
        )
    conv = JointConvention(maker, tuple(direction), tuple(couplings), external)
    if abs(np.linalg.det(conv.matrix())) < 1e-9:
        raise ConventionError("controller.couplings", "the joints' mapping is not invertible")
    return conv
