"""A UR's own factory calibration as a model file: the model its controller computes with.

Every Universal Robots arm leaves the factory with its own kinematic calibration, and its
controller computes poses (a waypoint's ``p`` from its ``q``, ``get_inverse_kin``) with it: on
real PolyScope exports UR's published table misses ``Waypoint_n_p`` by about 1.3 mm
(bench/ur_factory.md). A filter that models the controller must use that arm's table. It
comes in two forms, both read here into a model file (:mod:`calib.models`):

``calibration.conf`` (the controller's ``/root/.urcontrol/calibration.conf``)
    Section ``[mounting]``, keys ``delta_theta``, ``delta_a``, ``delta_d``, ``delta_alpha``:
    six numbers each [rad, m], ``#`` comments allowed. They are added to UR's published table
    (the library entry, ``calib/robots/library/ur*.toml``): ``a + delta_a``, ``d + delta_d``,
    ``alpha + delta_alpha`` and ``theta = delta_theta`` (the joint offset), as the controller
    does with its ``urcontrol.conf`` nominal (:func:`with_deltas`).
Primary interface (port 30001), robot-state package KinematicsInfo
    ``dh_theta, dh_a, dh_d, dh_alpha``: the whole calibrated table, as ROS's ur_calibration
    uses it (:func:`from_kinematics_info`; read by :mod:`drivers.ur_primary`).

Either table may carry ``d`` of hundreds of metres on axes 2-4 (nearly parallel axes meet
their common normal far away); the model keeps it as it is, and the filter solves it
(:mod:`calib.filter.ur_ik`).

``python -m calib.robots.ur_factory BASE.toml calibration.conf [NAME]`` prints the arm's
model file.
"""

from __future__ import annotations

import math
import re
import sys
import tomllib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from calib.kinematics import N_JOINTS
from calib.models import ModelError, RobotModel, model_from_mapping

KEYS = ("delta_theta", "delta_a", "delta_d", "delta_alpha")
SECTION = "mounting"
_SECTION = re.compile(r"^\s*\[([^\]]+)\]\s*(?:[#;].*)?$")
_ENTRY = re.compile(r"^\s*([A-Za-z_]\w*)\s*[=:]\s*(.*?)\s*$")


class FactoryCalibrationError(ValueError):
    """A calibration file that cannot be read; the message names the file, line and key."""


@dataclass(frozen=True)
class KinematicDeltas:
    """An arm's deltas to UR's published table, per joint: ``theta_rad``, ``a_m``, ``d_m``,
    ``alpha_rad`` (each 6 floats)."""

    theta_rad: tuple[float, ...]
    a_m: tuple[float, ...]
    d_m: tuple[float, ...]
    alpha_rad: tuple[float, ...]


def _numbers(raw: str, where: str) -> tuple[float, ...]:
    body = raw.split("#", 1)[0].strip()
    if not (body.startswith("[") and body.endswith("]")):
        raise FactoryCalibrationError(f"{where}: expected a list [v1, ..., v6], got {body!r}")
    items = [s.strip() for s in body[1:-1].split(",") if s.strip()]
    try:
        values = tuple(float(s) for s in items)
    except ValueError as exc:
        raise FactoryCalibrationError(f"{where}: {exc}") from exc
    if len(values) != N_JOINTS or not all(math.isfinite(v) for v in values):
        raise FactoryCalibrationError(f"{where}: expected 6 finite numbers, got {len(values)}")
    return values


def parse_calibration_conf(text: str, file: str = "calibration.conf") -> KinematicDeltas:
    """The ``[mounting]`` deltas of a ``calibration.conf``'s text.

    Raises
    ------
    FactoryCalibrationError
        A key missing or not six numbers (naming the file, line and key).
    """
    section = ""
    found: dict[str, tuple[float, ...]] = {}
    for number, line in enumerate(text.splitlines(), start=1):
        if not line.strip() or line.lstrip().startswith(("#", ";")):
            continue
        m = _SECTION.match(line)
        if m:
            section = m.group(1).strip()
            continue
        m = _ENTRY.match(line)
        if m and section == SECTION and m.group(1) in KEYS:
            found[m.group(1)] = _numbers(m.group(2), f"{file}:{number}: {SECTION}.{m.group(1)}")
    missing = [k for k in KEYS if k not in found]
    if missing:
        raise FactoryCalibrationError(
            f"{file}: [{SECTION}] has no {', '.join(missing)} (a UR's calibration.conf holds "
            "delta_theta, delta_a, delta_d and delta_alpha there)"
        )
    return KinematicDeltas(*(found[k] for k in KEYS))


def _require_ur(model: RobotModel) -> None:
    if model.convention != "dh" or model.controller.maker not in ("ur", None):
        raise ModelError(
            "controller.maker",
            f"robot {model.name}: a UR factory calibration applies to a UR model (classic DH, "
            f"maker 'ur'), not {model.controller.maker!r} / {model.convention!r}",
        )


def _model(
    model: RobotModel, rows: list[tuple[float, float, float, float]], name: str
) -> RobotModel:
    data = model.to_dict()
    data["name"] = name
    for j, (alpha_deg, a_mm, d_mm, theta_deg) in enumerate(rows):
        data["joints"][j].update(alpha_deg=alpha_deg, a_mm=a_mm, d_mm=d_mm, theta_deg=theta_deg)
    return model_from_mapping(data)


def with_deltas(model: RobotModel, deltas: KinematicDeltas, name: str | None = None) -> RobotModel:
    """UR's published ``model`` (a library entry) with an arm's ``calibration.conf`` deltas."""
    _require_ur(model)
    rows = []
    for j in range(N_JOINTS):
        alpha, a, d, theta = (float(v) for v in model.dh_table[j])
        rows.append(
            (
                alpha + math.degrees(deltas.alpha_rad[j]),
                a + 1000.0 * deltas.a_m[j],
                d + 1000.0 * deltas.d_m[j],
                theta + math.degrees(deltas.theta_rad[j]),
            )
        )
    return _model(model, rows, name or f"{model.name}-factory")


def from_kinematics_info(
    model: RobotModel,
    theta_rad: Sequence[float],
    a_m: Sequence[float],
    d_m: Sequence[float],
    alpha_rad: Sequence[float],
    name: str | None = None,
) -> RobotModel:
    """The arm's whole table as KinematicsInfo reports it, with ``model``'s limits and
    controller convention."""
    _require_ur(model)
    rows = [
        (math.degrees(alpha_rad[j]), 1000.0 * a_m[j], 1000.0 * d_m[j], math.degrees(theta_rad[j]))
        for j in range(N_JOINTS)
    ]
    return _model(model, rows, name or f"{model.name}-factory")


#: How far [mm] an arm's base height (``d1``) and forearm length (``a3``) may be from a
#: library UR arm's to be taken for it. Factory calibrations move them by at most 2.3 mm in
#: the three of UniversalRobots/Universal_Robots_ROS2_Driver
#: ``ur_calibration/test/calibration_test.cpp`` (while ``a2`` moves by up to 632 mm and
#: ``d2 … d4`` by hundreds of metres: near-parallel axes); the library arms differ by 32 mm
#: or more in ``a3``.
SAME_ARM_MM = 10.0


def library_ur_arm(a_m: Sequence[float], d_m: Sequence[float]) -> str:
    """The library's UR arm (``ur3e`` …) whose published ``d1`` and ``a3`` are both within
    :data:`SAME_ARM_MM` of a KinematicsInfo's ``dh_d``, ``dh_a`` [m] (the arm's own joint
    ranges and convention come from it).

    Raises
    ------
    ModelError
        No library UR arm is that near (field ``robot``: give the base arm by name).
    """
    from calib.models import BUILTIN_MODELS, builtin_model

    d1, a3 = 1000.0 * float(d_m[0]), 1000.0 * float(a_m[2])
    best, gap = "", math.inf
    for name in sorted(BUILTIN_MODELS):
        model = builtin_model(name)
        if model.controller.maker != "ur":
            continue
        off = max(abs(float(model.dh_table[0][2]) - d1), abs(float(model.dh_table[2][1]) - a3))
        if off < gap:
            best, gap = name, off
    if gap > SAME_ARM_MM:
        raise ModelError(
            "robot",
            f"the arm's d1 = {d1:.1f} mm, a3 = {a3:.1f} mm are no library UR arm's "
            f"(nearest {best}, {gap:.1f} mm off): give its base arm by name",
        )
    return best


def main(argv: Sequence[str]) -> int:
    """``BASE.toml calibration.conf [NAME]``: print the arm's model file (TOML)."""
    from calib.export import model_to_toml

    if len(argv) not in (2, 3):
        print(
            "usage: python -m calib.robots.ur_factory BASE.toml calibration.conf [NAME]",
            file=sys.stderr,
        )
        return 2
    base_path, conf_path = Path(argv[0]), Path(argv[1])
    try:
        base = model_from_mapping(tomllib.loads(base_path.read_text("utf-8")))
        deltas = parse_calibration_conf(conf_path.read_text("utf-8"), str(conf_path))
        arm = with_deltas(base, deltas, argv[2] if len(argv) == 3 else None)
    except (OSError, ValueError, tomllib.TOMLDecodeError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    comment = (
        f"{base.name} with the factory deltas of {conf_path.name} (calib/robots/ur_factory.py)"
    )
    print(model_to_toml(arm, [comment]), end="")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
