"""Check the Fanuc conventions on real controller backups (figures: bench/robots-fanuc.md).

Usage::

    git clone https://github.com/JuniorNatalin/VASC /tmp/VASC
    PYTHONPATH=. python bench/robots_fanuc_check.py /tmp/VASC

Every backup directory whose ``VERSION.VA`` or ``SYSMAST.VA`` names the R-2000iB/210F is
read: the user frames and tools of group 1 (``SYSFRAME.VA``) and every ``/POS`` entry of its
``.LS`` files. For each Cartesian position without extended axes, whose UF and UT are known,
all nominal solutions of ``calib/robots/library/fanuc-r2000ib-210f.toml`` are found (joint
limits widened to every branch and turns -1..1 of J4, J6: the rule is checked, not the
limits) and counted against its CONFIG under the rule of :mod:`calib.programs.fanuc.config`
and under the rule the filter used before (flip ``N`` when J5 >= 0, turns of J4, J5, J6).
"""

from __future__ import annotations

import re
import sys
from collections import Counter
from dataclasses import replace
from pathlib import Path

import numpy as np

from calib.filter.branches import nominal_solutions
from calib.kinematics import FloatArray
from calib.models import parse_model_text
from calib.programs.fanuc.config import TURN_JOINTS, elbow_letter, turn_window_deg
from calib.programs.rotations import frame, zyx_deg_to_matrix

ARM = "R-2000iB/210F"
MODEL = Path(__file__).parents[1] / "calib" / "robots" / "library" / "fanuc-r2000ib-210f.toml"
_NUM = r"[-+]?(?:\d+\.?\d*|\.\d+)"
_FRAME = re.compile(
    r"\[1,(\d+)\] = \s*Group: 1\s+Config:[^\n]*\n\s*X:\s*(N)\s+Y:\s*(N)\s+Z:\s*(N)\s*\n"
    r"\s*W:\s*(N)\s+P:\s*(N)\s+R:\s*(N)".replace("N", _NUM)
)


def _pose(v: list[float]) -> FloatArray:
    return frame(np.array(v[:3]), zyx_deg_to_matrix(v[5], v[4], v[3]))


def _frames(text: str, name: str) -> dict[int, FloatArray]:
    m = re.search(r"\$" + name + r"\s+Storage.*?\n(.*?)\n\[\*", text, re.S)
    out = {0: np.eye(4)}
    for e in _FRAME.finditer(m.group(1) if m else ""):
        out[int(e.group(1))] = _pose([float(x) for x in e.groups()[1:]])
    return out


def _positions(backup: Path) -> list[tuple[str, FloatArray, list[float]]]:
    """(CONFIG, flange frame in the base, X..R) of every usable Cartesian position, deduplicated."""
    sysframe = next((p for p in backup.iterdir() if p.name.lower() == "sysframe.va"), None)
    if sysframe is None:
        return []
    text = sysframe.read_text("latin-1")
    uframes, utools = _frames(text, "MNUFRAME"), _frames(text, "MNUTOOL")
    seen: dict[tuple[object, ...], tuple[str, FloatArray, list[float]]] = {}
    for ls in backup.rglob("*"):
        if ls.suffix.lower() != ".ls":
            continue
        pos = ls.read_text("latin-1").split("/POS", 1)
        for m in re.finditer(r"P\[\d+[^\]]*\]\{(.*?)\};", pos[1] if len(pos) > 1 else "", re.S):
            g = re.search(r"GP1:(.*?)(?=GP\d:|$)", m.group(1), re.S)
            cfg = re.search(r"(?:CONFIG|KONFIG)\s*:\s*'([^']*)'", g.group(1)) if g else None
            fields = dict(re.findall(r"\b([A-Z]\d?)\s*=\s*(" + _NUM + ")", g.group(1) if g else ""))
            uf_ut = re.search(r"UF : (\d+), UT : (\d+)", g.group(1) if g else "")
            if not (cfg and uf_ut) or any(k.startswith("E") for k in fields):
                continue
            if not all(k in fields for k in "XYZWPR"):
                continue
            uf, ut = (int(x) for x in uf_ut.groups())
            if uf not in uframes or ut not in utools:
                continue
            xyzwpr = [float(fields[k]) for k in "XYZWPR"]
            flange = uframes[uf] @ _pose(xyzwpr) @ np.linalg.inv(utools[ut])
            seen[(tuple(xyzwpr), uf, ut, cfg.group(1))] = (cfg.group(1), flange, xyzwpr)
    return list(seen.values())


def _fits(q: FloatArray, sh: int, el: int, config: str, old: bool) -> bool:
    letters, *turns = (s.strip() for s in config.split(","))
    if old:  # and U/D as the branch sign seen towards the wrist centre
        flip, joints, up = ("N" if q[4] >= 0 else "F"), (3, 4, 5), "U" if el > 0 else "D"
    else:
        flip, joints, up = ("F" if q[4] > 0 else "N"), TURN_JOINTS, elbow_letter(sh, el)
    mine = flip + up + ("T" if sh > 0 else "B")
    return mine == letters.replace(" ", "") and all(
        turn_window_deg(int(t))[0] <= q[j] < turn_window_deg(int(t))[1]
        for j, t in zip(joints, turns, strict=False)
    )


def main(root: Path) -> None:
    model = parse_model_text(MODEL.read_text(), "toml")
    # Every branch and the turns -1, 0, 1 of J4 and J6 (J1's range is one turn on this arm).
    wide = replace(
        model,
        joint_limits_deg=np.array(
            [[-180.0, 180.0]] * 3 + [[-540.0, 540.0]] + [[-180.0, 180.0], [-540.0, 540.0]]
        ),
    )
    wide = replace(wide, controller=type(model.controller)())  # solutions in table angles
    backups = sorted(
        {
            p.parent
            for p in root.rglob("*")
            if p.name.lower() in ("version.va", "sysmast.va") and ARM in p.read_text("latin-1")
        }
    )
    rows = [r for b in backups for r in _positions(b)]
    sol = nominal_solutions(wide, np.array([r[1] for r in rows]))
    count: Counter[str] = Counter()
    limits = np.asarray(model.joint_limits_deg)
    for i, (config, _, _) in enumerate(rows):
        ks = np.flatnonzero(sol.valid[i])
        q_ctrl = model.controller.to_controller_deg(sol.joints_deg[i, ks])
        signs = list(zip(sol.shoulder[i, ks], sol.elbow[i, ks], strict=True))
        if "B" in config.split(",")[0]:  # U/D behind axis 1, within the limits (_fits: e x s)
            inside = np.all((q_ctrl >= limits[:, 0]) & (q_ctrl <= limits[:, 1]), axis=1)
            for how, flip in (("elbow x shoulder", False), ("elbow towards the wrist", True)):
                n = sum(
                    _fits(q, s, e * s if flip else e, config, False)
                    for q, (s, e), ok in zip(q_ctrl, signs, inside, strict=True)
                    if ok
                )
                count[f"{config.split(',')[0]} within the limits, U/D as {how}: {n} fit"] += 1
        new = [
            k
            for k, q, (s, e) in zip(ks, q_ctrl, signs, strict=True)
            if _fits(q, s, e, config, False)
        ]
        old = [
            k
            for k, q, (s, e) in zip(ks, q_ctrl, signs, strict=True)
            if _fits(q, s, e, config, True)
        ]
        count["positions"] += 1
        count["new rule: exactly one"] += len(new) == 1
        if len(new) != 1:
            zero = not np.any(rows[i][2])
            count[
                f"new rule: {len(new)} ({'an all-zero placeholder' if zero else 'a position'})"
            ] += 1
        count["old rule: exactly one"] += len(old) == 1
        if len(new) == 1 and len(old) == 1:
            same = np.allclose(sol.joints_deg[i, new[0]], sol.joints_deg[i, old[0]])
            count["old rule: another solution than the new"] += not same
    print(f"backups of the {ARM}: {len(backups)}")
    print("CONFIG written:", Counter(r[0] for r in rows).most_common(6))
    for k, v in count.items():
        print(f"{k}: {v}")


if __name__ == "__main__":
    main(Path(sys.argv[1]))
