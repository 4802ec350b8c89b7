"""The robot library's checks (docs/robots.md): each built-in arm against what the world
writes of it, from fixtures written in the real shapes (tests/fixtures/robots/).

Two checks per ABB arm:

* **controller targets**: a RAPID module with pairs ``j_<tag>`` (jointtarget) and ``p_<tag>``
  (robtarget, tool0 in wobj0) of one pose; the arm's forward kinematics of the jointtarget
  against the robtarget: position [mm] and orientation [deg] (quaternion to matrix). The
  ``! pair <tag> arm=<name> seen=...`` comment names the arm and where the numbers were seen.
* **chain**: the arm's joint chain as ROS-Industrial's support package gives it (a URDF:
  origins and axes; the ABB driver hands those joint values to MoveAbsJ unchanged but for
  rad/deg, so they count as the controller), against the library model at random poses within
  the joint limits: the largest position [mm] and orientation [deg] difference of tool0.

Writes bench/robots.md and bench/robots.json. Run: ``python -m bench.robots_check``.
"""

from __future__ import annotations

import json
import re
import xml.etree.ElementTree as ET
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from calib.ik import tool_pose
from calib.kinematics import FloatArray
from calib.models import RobotModel
from calib.programs.rapid.syntax import blank, is_jointtarget, is_robtarget, parse_literal
from calib.programs.rotations import quat_wxyz_to_matrix, rotation_angle_deg
from calib.programs.sites import Source
from calib.robots import library_model

ROOT = Path(__file__).resolve().parent.parent
FIXTURES = ROOT / "tests" / "fixtures" / "robots"
TARGETS = FIXTURES / "abb_home_targets.mod"
#: Random poses per arm for the chain check.
CHAIN_POSES = 500
_DECL = re.compile(r"\b(jointtarget|robtarget)\s+([jp])_(\w+)\s*:=\s*", re.IGNORECASE)
_SOURCE = re.compile(r"\bas (\S+/\S+)\s+(\S+)")
_PAIR = re.compile(r"!\s*pair\s+(\w+)\s+arm=(\S+)\s+seen=(.*)")


@dataclass(frozen=True)
class PairCheck:
    """One jointtarget/robtarget pair: the FK of the joints against the robtarget."""

    tag: str
    arm: str
    seen: str
    joints_deg: list[float]
    position_error_mm: float
    rotation_error_deg: float


@dataclass(frozen=True)
class ChainCheck:
    """The library model against a URDF chain at random poses (the largest differences)."""

    arm: str
    source: str
    poses: int
    max_position_mm: float
    max_rotation_deg: float


def read_pairs(path: Path = TARGETS) -> list[tuple[str, str, str, FloatArray, FloatArray]]:
    """``(tag, arm, seen, joints (6,) [deg], robtarget frame (4, 4) [mm])`` of a module."""
    text = path.read_text(encoding="utf-8")
    source = Source(path.name, text, "utf-8")
    code = blank(text)
    joints: dict[str, FloatArray] = {}
    frames: dict[str, FloatArray] = {}
    for m in _DECL.finditer(code):
        node = parse_literal(code, m.end(), source)
        assert node.items is not None
        values = [[float(n.num or 0.0) for n in item.items or []] for item in node.items]
        if m.group(1).lower() == "jointtarget" and is_jointtarget(node):
            joints[m.group(3)] = np.array(values[0])
        elif is_robtarget(node):
            frame = np.eye(4)
            frame[:3, :3] = quat_wxyz_to_matrix(np.array(values[1]))
            frame[:3, 3] = values[0]
            frames[m.group(3)] = frame
    out = []
    for m in _PAIR.finditer(text):
        tag, arm, seen = m.group(1), m.group(2), m.group(3).strip()
        out.append((tag, arm, seen, joints[tag], frames[tag]))
    return out


def pair_checks(model_of: dict[str, RobotModel] | None = None) -> list[PairCheck]:
    """Every pair of :data:`TARGETS` against the library arm it names (or ``model_of``)."""
    out = []
    for tag, arm, seen, q, frame in read_pairs():
        model = (model_of or {}).get(arm) or library_model(arm)
        pos, rot = tool_pose(model, q[None, :], np.zeros(3))
        out.append(
            PairCheck(
                tag,
                arm,
                seen,
                q.tolist(),
                float(np.linalg.norm(pos[0] - frame[:3, 3])),
                float(rotation_angle_deg(rot[0], frame[:3, :3])),
            )
        )
    return out


def _floats(element: ET.Element | None, attr: str, default: str) -> FloatArray:
    text = element.get(attr, default) if element is not None else default
    return np.array([float(v) for v in text.split()])


def _urdf_chain(path: Path) -> list[tuple[str, FloatArray, FloatArray, FloatArray]]:
    """``(type, xyz [mm], rpy [rad], axis)`` of every joint from the base, in order."""
    root = ET.parse(path).getroot()
    by_parent = {}
    for j in root.iter("joint"):
        parent, child = j.find("parent"), j.find("child")
        if parent is not None and child is not None:
            by_parent[parent.get("link")] = (j, child.get("link"))
    chain = []
    link: str | None = "base_link"
    while link in by_parent:
        j, link = by_parent[link]
        xyz = 1000.0 * _floats(j.find("origin"), "xyz", "0 0 0")
        rpy = _floats(j.find("origin"), "rpy", "0 0 0")
        axis = _floats(j.find("axis"), "xyz", "0 0 1")
        chain.append((j.get("type") or "fixed", xyz, rpy, axis))
    return chain


def urdf_tool0(path: Path, q_deg: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Position (n, 3) [mm] and orientation (n, 3, 3) of the chain's last frame, joints
    (n, 6) [deg] in URDF order (each revolute joint turns about its axis)."""
    chain = _urdf_chain(path)
    n = q_deg.shape[0]
    rot = np.tile(np.eye(3), (n, 1, 1))
    pos = np.zeros((n, 3))
    k = 0
    for kind, xyz, rpy, axis in chain:
        pos = pos + rot @ xyz
        rot = rot @ Rotation.from_euler("xyz", rpy).as_matrix()
        if kind != "fixed":
            turn = Rotation.from_rotvec(np.radians(q_deg[:, k])[:, None] * axis).as_matrix()
            rot = rot @ turn
            k += 1
    return pos, rot


def chain_checks(
    poses: int = CHAIN_POSES, seed: int = 0, model_of: dict[str, RobotModel] | None = None
) -> list[ChainCheck]:
    """Every ``rosi-<arm>.urdf`` fixture against the library arm ``<arm>`` (or ``model_of``)."""
    rng = np.random.default_rng(seed)
    out = []
    for path in sorted(FIXTURES.glob("rosi-*.urdf")):
        arm = path.stem.removeprefix("rosi-")
        model = (model_of or {}).get(arm) or library_model(arm)
        limits = model.limits_deg()
        q = rng.uniform(limits[:, 0], limits[:, 1], size=(poses, 6))
        pos_m, rot_m = tool_pose(model, q, np.zeros(3))
        pos_u, rot_u = urdf_tool0(path, q)
        found = _SOURCE.search(path.read_text(encoding="utf-8"))
        source = f"{found.group(1)} {found.group(2)}" if found else "?"
        out.append(
            ChainCheck(
                arm,
                source,
                poses,
                float(np.max(np.linalg.norm(pos_m - pos_u, axis=1))),
                float(np.max(rotation_angle_deg(rot_m, rot_u))),
            )
        )
    return out


def _markdown(pairs: list[PairCheck], chains: list[ChainCheck], old: PairCheck) -> str:
    lines = [
        "# Robot library checks",
        "",
        "Written by `python -m bench.robots_check` from the fixtures in tests/fixtures/robots/",
        "(docs/robots.md says what each check proves and where the numbers were seen).",
        "",
        "## Controller targets: forward kinematics of the jointtarget against the robtarget",
        "",
        "| pair | arm | joints [deg] | position [mm] | orientation [deg] |",
        "|---|---|---|---:|---:|",
    ]
    for p in pairs:
        q = ", ".join(f"{v:g}" for v in p.joints_deg)
        lines.append(
            f"| {p.tag} | {p.arm} | {q} | {p.position_error_mm:.2g} | {p.rotation_error_deg:.2g} |"
        )
    lines += [
        "",
        f"The previous examples/abb-irb120.toml (joint 6 theta_deg 0) on pair {old.tag}: "
        f"{old.position_error_mm:.2g} mm, {old.rotation_error_deg:.1f} deg.",
        "",
        "## Chain: the library model against ROS-Industrial's URDF joint chain",
        "",
        "| arm | URDF | poses | max position [mm] | max orientation [deg] |",
        "|---|---|---:|---:|---:|",
    ]
    for c in chains:
        lines.append(
            f"| {c.arm} | {c.source} | {c.poses} | {c.max_position_mm:.2g} | "
            f"{c.max_rotation_deg:.2g} |"
        )
    return "\n".join(lines) + "\n"


def old_irb120_check() -> PairCheck:
    """The IRB 120 pair under the previous example model (joint 6 at theta_deg 0)."""
    arm = library_model("abb-irb120")
    table = np.array(arm.dh_table)
    table[5, 3] = 0.0
    old = RobotModel(arm.name, arm.convention, table, arm.joint_limits_deg, arm.tool_mm)
    return next(p for p in pair_checks({"abb-irb120": old}) if p.arm == "abb-irb120")


def main() -> None:
    pairs, chains, old = pair_checks(), chain_checks(), old_irb120_check()
    (ROOT / "bench" / "robots.md").write_text(_markdown(pairs, chains, old), encoding="utf-8")
    data = {
        "pairs": [asdict(p) for p in pairs],
        "chains": [asdict(c) for c in chains],
        "previous_irb120": asdict(old),
    }
    (ROOT / "bench" / "robots.json").write_text(json.dumps(data, indent=2) + "\n")
    print(_markdown(pairs, chains, old))


if __name__ == "__main__":
    main()
