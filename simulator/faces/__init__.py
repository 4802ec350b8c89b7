"""Emulated robot-controller faces: the cell's one robot served on each brand's protocol.

:data:`FACES` maps a robot kind (the daemon's ``[robot] kind``) to its face: the config table
of ``sim.toml`` (``[robot_abb_rws]`` …, each with ``enabled``, ``host``, ``port``), the key of
the READY mapping (``host:port``) and the server class, built as ``cls(cell, section)`` (see
:class:`simulator.faces.base.FaceServer`). :class:`simulator.runner.CellRunner` starts every
enabled face listed here. Adding a face is one module and one entry.
"""

from __future__ import annotations

from typing import NamedTuple

from simulator.faces.abb_rws import AbbRwsServer
from simulator.faces.base import FaceServer
from simulator.faces.fanuc_rmi import FanucRmiServer
from simulator.faces.kuka_varproxy import KukaVarProxyServer
from simulator.faces.ur_rtde import UrRtdeServer


class Face(NamedTuple):
    """One entry of :data:`FACES`."""

    table: str
    ready_key: str
    server: type[FaceServer]


#: Every face the cell can serve, by robot kind. A face whose server is not written yet is
#: absent (its READY key is then always null).
FACES: dict[str, Face] = {
    "abb-rws": Face("robot_abb_rws", "robot_abb_rws", AbbRwsServer),
    "ur-rtde": Face("robot_ur_rtde", "robot_ur_rtde", UrRtdeServer),
    "kuka-varproxy": Face("robot_kuka_varproxy", "robot_kuka_varproxy", KukaVarProxyServer),
    "fanuc-rmi": Face("robot_fanuc_rmi", "robot_fanuc_rmi", FanucRmiServer),
}

#: READY keys of every controller family's face, present (or null) in every READY mapping.
FACE_READY_KEYS = ("robot_abb_rws", "robot_ur_rtde", "robot_kuka_varproxy", "robot_fanuc_rmi")

__all__ = ["FACES", "FACE_READY_KEYS", "Face", "FaceServer"]
