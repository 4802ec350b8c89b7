"""Exports of a calibrated model: TOML and JSON model files (what ``--robot`` reads), and URDF.

A calibrated model is a model: :func:`model_from_result` turns a stored ``result.json`` (the
contract of :meth:`calib.identify.IdentifyResult.to_json`) into a :class:`RobotModel` with the
calibrated DH table and cable hook point, and the nominal model's joint limits. The TOML and
JSON exports are the model-file format of :mod:`calib.models` (floats written with Python's
shortest round-trip ``repr``, so a model loaded back is bit-identical). Anchor, zero offset
and metrics are not part of a model; the TOML header comments name the source.

URDF (for ROS users; lengths in metres, angles in radians). Each joint's fixed ``origin`` is
one rigid transform of the DH chain; the joint then rotates about its local ``z`` by the
controller's angle ``q``, so the URDF joint values are the controller's joint angles.

* Classic DH, ``K_i = Rz(θ_i + q_i) Tz(d_i) Tx(a_i) Rx(α_i) = Rz(q_i) C_i`` with
  ``C_i = Rz(θ_i) Tz(d_i) Tx(a_i) Rx(α_i)``: joint 1 has the identity origin, joint ``i`` the
  origin ``C_{i-1}``, and a fixed ``flange`` joint carries ``C_6``.
* Modified DH, ``K_i = Rx(α_{i-1}) Tx(a_{i-1}) Rz(θ_i + q_i) Tz(d_i)``. Since ``Rz(θ) Tz(d)``
  commutes with ``Rz(q)``, the chain regroups as ``Π_i D_i Rz(q_i)`` followed by
  ``Rz(θ_6) Tz(d_6)``, with ``D_i = Rz(θ_{i-1}) Tz(d_{i-1}) Tx(a_{i-1}) Rx(α_{i-1})``
  (``θ_0 = d_0 = 0``): the same shape as ``C``.

``Rz(θ) Tz(d) Tx(a) Rx(α)`` is the translation ``(a cos θ, a sin θ, d)`` and the rotation
``Rz(θ) Rx(α)``, which is URDF ``rpy = (α, 0, θ)`` exactly: no matrix-to-Euler conversion,
no gimbal-lock precision loss. A fixed ``tool_point`` link sits at the model's ``tool_mm``.
Revolute joints carry the model's limits (``effort`` and ``velocity`` are unknown and written
as 0); a model without limits gets ``continuous`` joints.
"""

from __future__ import annotations

import json
import math
import re
import xml.etree.ElementTree as ET
from collections.abc import Callable, Sequence
from typing import Any

import tomli_w

from calib.kinematics import N_JOINTS
from calib.models import RobotModel, model_from_mapping
from calib.result import DH_KEYS, CalibrationResult, ResultLike

EXPORT_FORMATS = ("toml", "json", "urdf")


def model_from_result(
    result: ResultLike, nominal: RobotModel | None = None, name: str | None = None
) -> RobotModel:
    """The calibrated robot of a result as a :class:`RobotModel`.

    Parameters
    ----------
    result : CalibrationResult or mapping
        ``robot``, ``convention``, ``dh`` (six rows with ``alpha_deg, a_mm, d_mm, theta_deg``)
        and ``tool_mm`` (the calibrated cable hook point).
    nominal : RobotModel, optional
        Source of the joint limits (a result does not store them).
    name : str, optional
        Default ``"<robot>-calibrated"``.

    Raises
    ------
    calib.result.ResultError, calib.models.ModelError
        Naming the missing or invalid field.
    """
    res = CalibrationResult.of(result)
    joints: list[dict[str, Any]] = []
    for j, row in enumerate(res.dh_rows()):
        joint: dict[str, Any] = dict(zip(DH_KEYS, row.values(), strict=True))
        if nominal is not None and nominal.joint_limits_deg is not None:
            joint["limits_deg"] = [float(v) for v in nominal.joint_limits_deg[j]]
        joints.append(joint)
    robot = res.robot if res.robot is not None else "robot"
    mapping: dict[str, Any] = {
        "name": name or f"{robot}-calibrated",
        "convention": res.convention or "dh",
        "tool_mm": list(res.tool_mm or (0.0, 0.0, 0.0)),
        "joints": joints,
    }
    if res.controller is not None:
        mapping["controller"] = res.controller
    return model_from_mapping(mapping)


#: Characters XML 1.0 has no place for, not even escaped: C0 controls but tab, LF and CR;
#: U+FFFE, U+FFFF; lone surrogates.
_XML_INVALID = re.compile("[\x00-\x08\x0b\x0c\x0e-\x1f\ufffe\uffff\ud800-\udfff]")
#: Control characters a one-line comment must not carry (line breaks included).
_COMMENT_CONTROL = re.compile("[\x00-\x1f\x7f-\x9f\u2028\u2029]")


def xml_text(text: str) -> str:
    """``text`` as XML 1.0 can carry it in an attribute or element (ElementTree escapes ``&``,
    ``<``, ``"`` and line breaks itself): characters XML cannot hold become U+FFFD."""
    return _XML_INVALID.sub("\ufffd", text)


def xml_comment(text: str) -> str:
    """``text`` as the body of one ``<!-- … -->`` comment: one line, no ``--`` (which would
    end the comment or make the XML invalid) and no ``-`` at its end."""
    body = _COMMENT_CONTROL.sub(" ", xml_text(text))
    while "--" in body:
        body = body.replace("--", "- -")
    return body + " " if body.endswith("-") else body


def toml_comment(text: str) -> list[str]:
    """``text`` as the bodies of TOML ``#`` comment lines, one per line of ``text``: TOML allows
    no control character but the tab in a comment, so the others become U+FFFD."""
    return [_COMMENT_CONTROL.sub("\ufffd", line) for line in text.splitlines()]


def model_to_toml(model: RobotModel, comments: Sequence[str] = ()) -> str:
    """The model as a TOML model file (``--robot FILE.toml``), with ``#`` comment lines first."""
    head = "".join(f"# {line}\n" for c in comments for line in toml_comment(c))
    return head + tomli_w.dumps(model.to_dict())


def model_to_json(model: RobotModel) -> str:
    """The model as a JSON model file (``--robot FILE.json``)."""
    return json.dumps(model.to_dict(), indent=2) + "\n"


def _num(value: float) -> str:
    return repr(float(value))


def _origin(theta_rad: float, d_mm: float, a_mm: float, alpha_rad: float) -> dict[str, str]:
    """URDF ``origin`` attributes of ``Rz(θ) Tz(d) Tx(a) Rx(α)`` (metres, radians)."""
    xyz = (a_mm * math.cos(theta_rad) / 1000.0, a_mm * math.sin(theta_rad) / 1000.0, d_mm / 1000.0)
    return {"xyz": " ".join(map(_num, xyz)), "rpy": f"{_num(alpha_rad)} 0.0 {_num(theta_rad)}"}


def _joint_origins(model: RobotModel) -> list[dict[str, str]]:
    """Seven origins: joints 1..6 and the fixed flange joint (see the module docstring)."""
    dh = model.dh_internal()  # (6, 4): alpha_rad, a_mm, d_mm, theta_rad
    if model.convention == "dh":
        out = [_origin(0.0, 0.0, 0.0, 0.0)]
        out += [_origin(dh[j, 3], dh[j, 2], dh[j, 1], dh[j, 0]) for j in range(N_JOINTS)]
        return out
    out = []
    for j in range(N_JOINTS):
        theta_prev, d_prev = (dh[j - 1, 3], dh[j - 1, 2]) if j else (0.0, 0.0)
        out.append(_origin(theta_prev, d_prev, dh[j, 1], dh[j, 0]))
    out.append(_origin(dh[-1, 3], dh[-1, 2], 0.0, 0.0))
    return out


def _axis(model: RobotModel, j: int) -> str:
    """URDF ``axis`` of joint ``j`` (0-based): ``z``, or ``-z`` where the controller counts
    the joint opposite to the table (so the URDF joint value is the controller's angle)."""
    return "0 0 -1" if model.controller.direction[j] == -1 else "0 0 1"


def _joint_values_note(model: RobotModel) -> str:
    """What a URDF joint value is: the controller's angle, unless the controller couples
    joints (URDF has no coupling: then the value is the table angle, and the rule is said)."""
    if not model.controller.couplings:
        return "joint values are the controller's joint angles"
    direction = model.controller.direction
    terms = "; ".join(
        f"joint_{j + 1} = J{j + 1} {'+' if direction[j] * f >= 0 else '-'} {abs(f):g} * J{k + 1}"
        for j, k, f in model.controller.couplings
    )
    return (
        "joint values are the controller's joint angles J1..J6 except where the controller "
        f"couples joints, which URDF cannot: {terms}; the limits are the controller's"
    )


def model_to_urdf(model: RobotModel) -> str:
    """The model as URDF text: links ``base_link, link_1 … link_6, flange, tool_point``,
    revolute joints ``joint_1 … joint_6`` about ``z``, fixed ``flange`` and ``tool_point``."""
    robot = ET.Element("robot", name=xml_text(model.name))
    links = ["base_link", *(f"link_{j + 1}" for j in range(N_JOINTS)), "flange", "tool_point"]
    for link in links:
        ET.SubElement(robot, "link", name=link)
    origins = _joint_origins(model)
    limits = model.joint_limits_deg
    for j in range(N_JOINTS + 2):
        if j < N_JOINTS:
            name, kind = f"joint_{j + 1}", ("continuous" if limits is None else "revolute")
        else:
            name, kind = ("flange", "tool_point")[j - N_JOINTS], "fixed"
        joint = ET.SubElement(robot, "joint", name=name, type=kind)
        ET.SubElement(joint, "parent", link=links[j])
        ET.SubElement(joint, "child", link=links[j + 1])
        if j <= N_JOINTS:
            ET.SubElement(joint, "origin", attrib=origins[j])
        else:
            tool_m = " ".join(_num(v / 1000.0) for v in model.tool_mm)
            ET.SubElement(joint, "origin", xyz=tool_m, rpy="0.0 0.0 0.0")
        if j < N_JOINTS:
            ET.SubElement(joint, "axis", xyz=_axis(model, j))
            if limits is not None:
                lo, hi = (_num(math.radians(v)) for v in limits[j])
                ET.SubElement(joint, "limit", lower=lo, upper=hi, effort="0", velocity="0")
    ET.indent(robot)
    comment = (
        f"<!-- {xml_comment(model.name)}: {model.convention} chain exported by cablecal; "
        f"lengths in m, angles in rad; {_joint_values_note(model)} -->\n"
    )
    return '<?xml version="1.0"?>\n' + comment + ET.tostring(robot, encoding="unicode") + "\n"


#: Format name → writer (a table, not an if-chain).
WRITERS: dict[str, Callable[[RobotModel], str]] = {
    "toml": model_to_toml,
    "json": model_to_json,
    "urdf": model_to_urdf,
}


def export_model(model: RobotModel, fmt: str) -> str:
    """The model in ``fmt`` (one of :data:`EXPORT_FORMATS`)."""
    if fmt not in WRITERS:
        raise ValueError(f"format: must be one of {EXPORT_FORMATS}, got {fmt!r}")
    return WRITERS[fmt](model)


def export_result(result: ResultLike, fmt: str, nominal: RobotModel | None = None) -> str:
    """A result's calibrated model in ``fmt``; TOML gets a header naming the source (robot,
    method, identification RMSE) and what a model file leaves out."""
    res = CalibrationResult.of(result)
    model = model_from_result(res, nominal)
    if fmt != "toml":
        return export_model(model, fmt)
    test, train = res.figures("after", "test"), res.figures("after", "train")
    rmse = test.get("rmse_mm") if test.get("n") else train.get("rmse_mm")
    comments = [
        f"Calibrated model of {res.robot!r} (method {res.method!r}), "
        f"identification RMSE {rmse} mm.",
        "The cable anchor and zero offset are not part of a model. tool_mm is the calibrated",
        "cable hook point. Joint limits are the nominal model's"
        + ("." if nominal is not None and nominal.joint_limits_deg is not None else " (none)."),
    ]
    return model_to_toml(model, comments)
