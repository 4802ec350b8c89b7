"""Fanuc's configuration string ``CONFIG : 'F U T, t1, t4, t6'``, one rule each.

Proven on real controller backups (docs/robots-fanuc.md names them and the figures): a
position held in joint form and its Cartesian twin agree only under these rules, in Fanuc's
own joint angles (what the pendant shows; the J2/J3 coupling and the joint directions are
the model's ``[controller]`` table, :mod:`calib.conventions`).

* **Flip** ``F``/``N``: ``F`` when J5 > 0, ``N`` when J5 ≤ 0 (:func:`flip_letter`).
* **Front/back** ``T``/``B``: the branch sign ``shoulder`` of
  :class:`calib.programs.sites.Configuration` (+1 is ``T``: the wrist centre in front of
  axis 1).
* **Elbow** ``U``/``D``: up or down as seen along the arm's own forward direction (frame
  1's x axis), so in front (``T``) ``U`` is the branch sign ``elbow`` +1 and behind (``B``)
  it is ``elbow`` -1 (:func:`elbow_letter`; the branch sign looks towards the wrist centre).
* **Turn numbers**: those of J1, J4 and J6 (:data:`TURN_JOINTS`), in that order; turn ``k``
  is the window ``[-180 + 360k, 180 + 360k)`` deg (:func:`turn_number`), so J4 = 180.000
  is turn 1 (a real backup's typed position says so).

The keyword is ``CONFIG``, or ``KONFIG`` on a controller set to German (:data:`KEYWORDS`).

A correction that would change any of these is refused (:func:`refusal`): the controller
would take another branch, alarm, or turn a joint a full turn.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from functools import lru_cache

import numpy as np

from calib.kinematics import N_JOINTS, FloatArray
from calib.programs.sites import Configuration

#: Joints (0-based) whose turn numbers the CONFIG string carries, in its order: J1, J4, J6.
TURN_JOINTS = (0, 3, 5)
#: The flip joint (0-based): J5.
FLIP_JOINT = 4
#: Turn windows are read shifted down by this [deg], ``[-180 + 360k - e, 180 + 360k - e)``: the
#: nominal solution of a position at J4 = 180.000 (turn 1) may come out as 179.99999, and one
#: at -180.000 (turn 0) as -180.00001; each still lies in its own window, and never in two.
TURN_EDGE_DEG = 0.001
#: The words a controller writes before the string (English, German).
KEYWORDS = ("CONFIG", "KONFIG")
#: Letter → (field, sign); the elbow's becomes the branch sign ``elbow`` times ``shoulder``.
LETTERS = {
    "F": ("wrist", 1),
    "N": ("wrist", -1),
    "U": ("elbow", 1),
    "D": ("elbow", -1),
    "T": ("shoulder", 1),
    "B": ("shoulder", -1),
}


def turn_number(angle_deg: float) -> int:
    """The turn number of a joint angle [deg]: ``k`` with the angle in
    ``[-180 + 360k, 180 + 360k)``."""
    return math.floor((angle_deg + 180.0) / 360.0)


def turn_window_deg(turn: int, edge_deg: float = TURN_EDGE_DEG) -> tuple[float, float]:
    """The half-open window ``[lo, hi)`` [deg] a nominal solution of turn number ``turn`` is
    read in: the turn's window shifted down by ``edge_deg`` (see :data:`TURN_EDGE_DEG`)."""
    return (-180.0 + 360.0 * turn - edge_deg, 180.0 + 360.0 * turn - edge_deg)


def flip_letter(j5_deg: float) -> str:
    """``F`` when J5 > 0 (Fanuc's angle), else ``N``."""
    return "F" if j5_deg > 0 else "N"


def elbow_letter(shoulder: int, elbow: int) -> str:
    """``U`` or ``D`` of the branch signs ``shoulder`` and ``elbow``: ``U`` when their product
    is +1 (see the module docstring)."""
    return "U" if shoulder * elbow > 0 else "D"


def config_text(q_deg: Sequence[float], shoulder: int, elbow: int) -> str:
    """``'F U T, t1, t4, t6'`` (without quotes) of Fanuc joint angles (6,) [deg] and the
    branch signs of :class:`calib.programs.sites.Configuration`."""
    letters = f"{flip_letter(q_deg[FLIP_JOINT])} {elbow_letter(shoulder, elbow)} "
    letters += "T" if shoulder > 0 else "B"
    return ", ".join([letters, *(str(turn_number(q_deg[j])) for j in TURN_JOINTS)])


@lru_cache(maxsize=1024)
def configuration(text: str, turns: tuple[int, ...]) -> Configuration:
    """The branch a Fanuc controller takes for the CONFIG string ``text`` (its letters; the
    turn numbers ``turns`` are read by the dialect, in the order of :data:`TURN_JOINTS`).

    Raises
    ------
    ValueError
        An unknown or repeated letter, or more turn numbers than :data:`TURN_JOINTS`.
    """
    letters = text.split(",")[0]
    signs: dict[str, int] = {}
    for ch in re.sub(r"\s+", "", letters).upper():
        if ch not in LETTERS or LETTERS[ch][0] in signs:
            raise ValueError(f"CONFIG '{text}': unexpected letter {ch!r}")
        signs[LETTERS[ch][0]] = LETTERS[ch][1]
    if len(turns) > len(TURN_JOINTS):
        raise ValueError(f"CONFIG '{text}': more than {len(TURN_JOINTS)} turn numbers")
    ranges = np.tile([-np.inf, np.inf], (N_JOINTS, 1))
    for j, k in zip(TURN_JOINTS, turns, strict=False):
        ranges[j] = turn_window_deg(k)
    shoulder, up = signs.get("shoulder"), signs.get("elbow")
    return Configuration(
        ranges,
        shoulder=shoulder,
        elbow=None if up is None or shoulder is None else up * shoulder,
        wrist=signs.get("wrist"),
        text=f"'{text}'",
    )


def refusal(config: Configuration, q_deg: FloatArray) -> str:
    """Why joints (6,) [deg, Fanuc's] cannot be written under ``config``: the flip or a turn
    number would change; empty when they keep it. (Elbow and front/back are the core's
    branch check.)"""
    if config.wrist is not None:
        letter = "F" if config.wrist > 0 else "N"
        if flip_letter(float(q_deg[FLIP_JOINT])) != letter:
            return (
                f"would change the flip {letter} (J5={float(q_deg[FLIP_JOINT]):.3f} deg): "
                "the wrist singularity lies between"
            )
    for j in TURN_JOINTS:
        lo, hi = config.joint_ranges_deg[j]
        q = float(q_deg[j])
        if not lo <= q < hi:
            written = turn_number((lo + hi) / 2.0) if math.isfinite(lo) else None
            return (
                f"would change the turn number of J{j + 1} ({written} -> {turn_number(q)}, "
                f"J{j + 1}={q:.3f} deg)"
            )
    return ""
