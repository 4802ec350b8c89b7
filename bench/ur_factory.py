"""UR on real PolyScope exports: the factory calibration's size, and the filter's UR rule.

Run on ``.script`` files taken from public repositories (not kept here; bench/ur_factory.md
names each repository, path and commit)::

    PYTHONPATH=. python bench/ur_factory.py DIR_OR_FILES... > table.md

Per file:

* **The factory calibration's size.** Every ``NAME_p`` / ``NAME_q`` pair PolyScope wrote
  (``global NAME_p=p[…]`` beside ``global NAME_q=[…]``, the controller's own pose of its own
  joints, TCP zero in these files: ``set_tcp(p[0,…])``) against the forward kinematics of
  ``q`` with UR's published table (the library entry that fits best, ``calib/robots/library``):
  the position gap [mm] and the orientation gap [deg], max and median.
* **The UR rule on the real text.** ``cablecal filter`` with that library model and a
  calibration equal to it: every byte kept?, targets corrected / left (with the reasons),
  and for each waypoint the largest joint gap [deg] between the nominal solution the filter
  picked (nearest ``NAME_q``) and ``NAME_q`` itself: the factory calibration's size in joint
  space when the rule picks the waypoint's own branch, tens of degrees when it does not.
* **A pure shift** (``d1 + 0.3 mm``): each corrected pose moves by 0.3 mm (max error [mm]).
* **A pure turn** (``theta1 + 0.05°``): each corrected ``NAME_q`` changes on joint 1 only, by
  −0.05° (max error on joint 1 and max change of joints 2–6 [deg]).
* **A realistic calibration** (every ``a, d`` of the table off by N(0, 0.3 mm), every
  ``alpha, theta`` by N(0, 0.03°), seeded): targets corrected / targets.
"""

from __future__ import annotations

import re
import sys
import tomllib
from pathlib import Path

import numpy as np

from calib.filter.correct import Calibration
from calib.filter.kin import flange_frames
from calib.filter.run import filter_files
from calib.models import RobotModel, model_from_mapping
from calib.programs.rotations import rotation_angle_deg, rotvec_to_matrix

LIBRARY = Path(__file__).resolve().parent.parent / "calib" / "robots" / "library"
_NUM = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
_PAIR_P = re.compile(r"global\s+(\w+)_p\s*=\s*p\[([^\]]*)\]")
_PAIR_Q = re.compile(r"global\s+(\w+)_q\s*=\s*\[([^\]]*)\]")


def _library() -> dict[str, RobotModel]:
    return {
        p.stem: model_from_mapping(tomllib.loads(p.read_text("utf-8")))
        for p in sorted(LIBRARY.glob("ur*.toml"))
    }


def _pairs(text: str) -> tuple[list[str], np.ndarray, np.ndarray]:
    ps = {
        m.group(1): [float(x) for x in re.findall(_NUM, m.group(2))] for m in _PAIR_P.finditer(text)
    }
    qs = {
        m.group(1): [float(x) for x in re.findall(_NUM, m.group(2))] for m in _PAIR_Q.finditer(text)
    }
    names = [n for n in ps if n in qs and len(ps[n]) == 6 and len(qs[n]) == 6]
    return names, np.array([ps[n] for n in names]), np.rad2deg(np.array([qs[n] for n in names]))


def _gaps(model: RobotModel, p: np.ndarray, q_deg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    fk = flange_frames(model, q_deg)
    pos = np.linalg.norm(fk[:, :3, 3] - 1000.0 * p[:, :3], axis=1)
    rot = rotation_angle_deg(fk[:, :3, :3], rotvec_to_matrix(p[:, 3:]))
    return pos, rot


def _changed(model: RobotModel, row: int, col: int, delta: float) -> RobotModel:
    table = model.dh_table.copy()
    table[row, col] += delta
    return RobotModel("changed", "dh", table, model.joint_limits_deg)


def _realistic(model: RobotModel) -> RobotModel:
    rng = np.random.default_rng(34)
    table = model.dh_table.copy()
    table[:, 1:3] += rng.normal(0.0, 0.3, (6, 2))
    table[:, [0, 3]] += rng.normal(0.0, 0.03, (6, 2))
    return RobotModel("realistic", "dh", table, model.joint_limits_deg)


def main(paths: list[str]) -> None:
    files = [
        f
        for p in paths
        for f in (sorted(Path(p).glob("*.script")) if Path(p).is_dir() else [Path(p)])
    ]
    arms = _library()
    print(
        "| file | pairs | arm | pos gap max / median [mm] | rot gap max / median [deg] "
        "| bytes kept | corrected / left | nearest-q gap max [deg] | d1+0.3: max error [mm] "
        "| theta1+0.05: J1 error / J2-6 change [deg] | realistic: corrected |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for path in files:
        data = path.read_bytes()
        names, p, q = _pairs(data.decode("utf-8", "replace"))
        if not names:
            continue
        fits = {k: _gaps(m, p, q) for k, m in arms.items()}
        arm = min(fits, key=lambda k: float(np.median(fits[k][0])))
        pos, rot = fits[arm]
        model = arms[arm]
        zero = np.zeros(0, dtype=int)
        run = filter_files(Calibration(model, model, None, zero), [(path.name, data)])
        kept = run.outputs.get(path.name) == data
        corrected = sum(c.status == "corrected" for c in run.corrections)
        left = {c.reason for c in run.corrections if c.status != "corrected"}
        by = {t.name: c for t, c in zip(run.targets, run.corrections, strict=True)}
        near = [
            float(np.max(np.abs(by[f"{n}_p"].nominal_joints_deg - q[k])))  # type: ignore[operator]
            for k, n in enumerate(names)
            if f"{n}_p" in by and by[f"{n}_p"].nominal_joints_deg is not None
        ]
        shift = filter_files(
            Calibration(model, _changed(model, 0, 2, 0.3), None, zero), [(path.name, data)]
        )
        turn = filter_files(
            Calibration(model, _changed(model, 0, 3, 0.05), None, zero), [(path.name, data)]
        )
        j1, rest = 0.0, 0.0
        for t, c in zip(turn.targets, turn.corrections, strict=True):
            if t.kind == "joint" and c.status == "corrected" and t.joints_deg is not None:
                delta = c.joints_deg - t.joints_deg  # type: ignore[operator]
                j1 = max(j1, abs(float(delta[0]) + 0.05))
                rest = max(rest, float(np.max(np.abs(delta[1:]))))
        real = filter_files(Calibration(model, _realistic(model), None, zero), [(path.name, data)])
        n_real = sum(c.status == "corrected" for c in real.corrections)
        errs = [
            abs(c.shift_mm - 0.3)
            for t, c in zip(shift.targets, shift.corrections, strict=True)
            if c.status == "corrected" and t.kind == "cartesian"
        ]
        print(
            f"| {path.name} | {len(names)} | {arm} | {pos.max():.3f} / {np.median(pos):.3f} "
            f"| {rot.max():.4f} / {np.median(rot):.4f} | {'yes' if kept else 'NO'} "
            f"| {corrected} / {len(run.corrections) - corrected}"
            f"{' (' + '; '.join(sorted(left)) + ')' if left else ''} "
            f"| {max(near) if near else float('nan'):.3f} "
            f"| {max(errs) if errs else float('nan'):.4f} ({len(errs)} poses) "
            f"| {j1:.6f} / {rest:.6f} | {n_real} / {len(real.corrections)} |"
        )


if __name__ == "__main__":
    main(sys.argv[1:])
