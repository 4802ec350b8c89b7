"""Robot models: nominal DH tables, joint limits and the nominal cable attachment point.

A model is plain data. It is built from a mapping (parsed from TOML or JSON by the caller, or
from text with :func:`parse_model_text`), validated field by field; every error names the field
(``joints[3].a_mm``). File format::

    name = "my-robot"
    convention = "dh"            # "dh" (classic, the paper's eq. (1)) or "mdh" (Craig)
    tool_mm = [0.0, 0.0, 120.0]  # optional, nominal cable hook point in the flange frame [mm]

    [[joints]]                   # exactly six
    alpha_deg = -90.0
    a_mm = 250.0
    d_mm = 653.5
    theta_deg = 0.0              # joint offset added to the controller's joint angle
    limits_deg = [-180, 180]     # optional [min, max], in the controller's angles

    [controller]                 # optional: how the controller counts its joints
    maker = "abb"                # (calib.conventions; without it the angles are the table's)
    direction = [1, 1, 1, 1, 1, 1]
"""

from __future__ import annotations

import json
import math
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from calib.conventions import (
    IDENTITY,
    ConventionError,
    JointConvention,
    controller_block,
    convention_from_mapping,
)
from calib.kinematics import N_JOINTS, Convention, FloatArray
from calib.robots.files import LibraryError, library_mapping, library_names

#: Limits used for a model without ``limits_deg`` [deg], in the controller's angles.
DEFAULT_LIMITS_DEG = (-170.0, 170.0)
#: Sampled poses (synthetic cells, the generic identifiability check) stay within ±this [deg]
#: of zero where a joint's range allows: realistic calibration poses avoid full-turn angles.
POSE_CLIP_DEG = 170.0


class ModelError(ValueError):
    """A robot model file or mapping is invalid; ``field`` names the offending entry."""

    def __init__(self, field_name: str, message: str) -> None:
        super().__init__(f"{field_name}: {message}")
        self.field = field_name


@dataclass(frozen=True)
class RobotModel:
    """Nominal kinematics of a 6R robot.

    Attributes
    ----------
    name : str
    convention : {"dh", "mdh"}
    dh_table : ndarray, shape (6, 4)
        Per joint ``(alpha_deg, a_mm, d_mm, theta_deg)``.
    joint_limits_deg : ndarray, shape (6, 2) or None
        ``[min, max]`` per joint [deg]; None when unknown.
    tool_mm : ndarray, shape (3,)
        Nominal cable attachment point in the flange frame [mm].
    controller : JointConvention
        How the controller counts its joints against ``dh_table`` (identity by default).
    """

    name: str
    convention: Convention
    dh_table: FloatArray
    joint_limits_deg: FloatArray | None = None
    tool_mm: FloatArray = field(default_factory=lambda: np.zeros(3))
    controller: JointConvention = IDENTITY

    def dh_internal(self) -> FloatArray:
        """The DH table in internal units, shape (6, 4): ``(alpha_rad, a_mm, d_mm, theta_rad)``."""
        out = np.array(self.dh_table, dtype=float)
        out[:, [0, 3]] = np.deg2rad(out[:, [0, 3]])
        return out

    def table_rad(self, q_ctrl_deg: Any) -> FloatArray:
        """Table angles [rad] of controller joint angles [deg], shape (6,) or (n, 6) kept.

        The one door from the controller's angles into the kinematics
        (:mod:`calib.conventions`); the table's ``theta_deg`` is added by the kinematics.
        With an identity convention this is ``np.deg2rad(q)``, bit for bit.
        """
        out: FloatArray = np.deg2rad(self.controller.to_table_deg(q_ctrl_deg))
        return out

    def controller_deg(self, q_table_rad: Any) -> FloatArray:
        """Controller joint angles [deg] of table angles [rad] (e.g. an IK solution), shape
        kept; the inverse of :meth:`table_rad`."""
        out: FloatArray = self.controller.to_controller_deg(np.rad2deg(q_table_rad))
        return out

    def limits_deg(self) -> FloatArray:
        """Joint limits, shape (6, 2) [deg] in the controller's angles; ±170 deg
        (:data:`DEFAULT_LIMITS_DEG`) for a model without them."""
        if self.joint_limits_deg is None:
            return np.tile(DEFAULT_LIMITS_DEG, (N_JOINTS, 1))
        return np.asarray(self.joint_limits_deg, dtype=float)

    def controller_fields(self) -> dict[str, Any]:
        """``{"controller": …}`` when the controller does not count as the table, else empty
        (model files and result.json alike: :func:`calib.conventions.controller_block`)."""
        return controller_block(self.controller)

    def to_dict(self) -> dict[str, Any]:
        """The model as a JSON-able mapping in the file format above."""
        joints: list[dict[str, Any]] = []
        for j in range(N_JOINTS):
            alpha, a, d, theta = (float(v) for v in self.dh_table[j])
            row: dict[str, Any] = {"alpha_deg": alpha, "a_mm": a, "d_mm": d, "theta_deg": theta}
            if self.joint_limits_deg is not None:
                row["limits_deg"] = [float(v) for v in self.joint_limits_deg[j]]
            joints.append(row)
        return {
            "name": self.name,
            "convention": self.convention,
            "tool_mm": [float(v) for v in self.tool_mm],
            "joints": joints,
            **self.controller_fields(),
        }


def _number(value: Any, field_name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ModelError(field_name, f"must be a number, got {value!r}")
    out = float(value)
    if not math.isfinite(out):
        raise ModelError(field_name, f"must be finite, got {value!r}")
    return out


def _vector(value: Any, length: int, field_name: str) -> list[float]:
    if not isinstance(value, Sequence) or isinstance(value, str) or len(value) != length:
        raise ModelError(field_name, f"must be a list of {length} numbers, got {value!r}")
    return [_number(v, f"{field_name}[{i}]") for i, v in enumerate(value)]


def model_from_mapping(data: Mapping[str, Any]) -> RobotModel:
    """Validate a parsed model mapping and build a :class:`RobotModel`.

    Raises
    ------
    ModelError
        Naming the first invalid field.
    """
    if not isinstance(data, Mapping):
        raise ModelError("<root>", "a model must be a table/object")
    known = {"name", "convention", "tool_mm", "joints", "controller"}
    for key in data:
        if key not in known:
            raise ModelError(str(key), f"unknown field (expected one of {sorted(known)})")
    name = data.get("name")
    if not isinstance(name, str) or not name.strip():
        raise ModelError("name", "must be a non-empty string")
    convention = data.get("convention", "dh")
    if convention not in ("dh", "mdh"):
        raise ModelError("convention", f"must be 'dh' or 'mdh', got {convention!r}")
    tool = _vector(data.get("tool_mm", [0.0, 0.0, 0.0]), 3, "tool_mm")
    joints = data.get("joints")
    if not isinstance(joints, Sequence) or isinstance(joints, str):
        raise ModelError("joints", "must be a list of six joint tables")
    if len(joints) != N_JOINTS:
        raise ModelError("joints", f"must have exactly {N_JOINTS} entries, got {len(joints)}")
    table = np.zeros((N_JOINTS, 4))
    limits = np.zeros((N_JOINTS, 2))
    n_limits = 0
    joint_keys = ("alpha_deg", "a_mm", "d_mm", "theta_deg")
    for j, joint in enumerate(joints):
        prefix = f"joints[{j + 1}]"
        if not isinstance(joint, Mapping):
            raise ModelError(prefix, "must be a table/object")
        for key in joint:
            if key not in (*joint_keys, "limits_deg"):
                raise ModelError(f"{prefix}.{key}", "unknown field")
        for k, key in enumerate(joint_keys):
            if key not in joint:
                raise ModelError(f"{prefix}.{key}", "is required")
            table[j, k] = _number(joint[key], f"{prefix}.{key}")
        if "limits_deg" in joint:
            lo, hi = _vector(joint["limits_deg"], 2, f"{prefix}.limits_deg")
            if not lo < hi:
                raise ModelError(f"{prefix}.limits_deg", f"min {lo} must be below max {hi}")
            limits[j] = (lo, hi)
            n_limits += 1
    if n_limits not in (0, N_JOINTS):
        raise ModelError("joints", "limits_deg must be given for all six joints or for none")
    if np.any(np.abs(table[:, [0, 3]]) > 360.0):
        raise ModelError("joints", "alpha_deg and theta_deg must lie within ±360")
    try:
        controller = convention_from_mapping(data.get("controller"))
    except ConventionError as exc:
        raise ModelError(exc.field, exc.message) from exc
    return RobotModel(
        name=name.strip(),
        convention=convention,
        dh_table=table,
        joint_limits_deg=limits if n_limits else None,
        tool_mm=np.asarray(tool, dtype=float),
        controller=controller,
    )


def parse_model_text(text: str, fmt: str) -> RobotModel:
    """Parse a model from TOML or JSON text.

    Parameters
    ----------
    text : str
        File contents.
    fmt : {"toml", "json"}
    """
    try:
        if fmt == "toml":
            data: Any = tomllib.loads(text)
        elif fmt == "json":
            data = json.loads(text)
        else:
            raise ModelError("<format>", f"unknown model format {fmt!r}; use toml or json")
    except (tomllib.TOMLDecodeError, json.JSONDecodeError) as exc:
        raise ModelError("<syntax>", str(exc)) from exc
    return model_from_mapping(data)


#: The paper's Table I (the library's ``hsr-jr680``, where its leading comment says why every
#: theta_deg offset is 0 and where the joint limits come from).
HSR_JR680: dict[str, Any] = library_mapping("hsr-jr680")

#: Every built-in arm's model mapping by name: the robot library (:mod:`calib.robots`).
BUILTIN_MODELS: dict[str, dict[str, Any]] = {
    name: library_mapping(name) for name in library_names()
}


def builtin_model(name: str) -> RobotModel:
    """A built-in model by name (``cablecal robots`` lists them)."""
    if name not in BUILTIN_MODELS:
        raise ModelError("robot", str(LibraryError(name)))
    return model_from_mapping(BUILTIN_MODELS[name])
