"""EMULATED Universal Robots RTDE face (Real-Time Data Exchange, protocol version 2).

Speaks RTDE as UR's "Real-Time Data Exchange (RTDE) Guide" describes it, so UR's own clients
(ur_rtde's ``RTDEReceiveInterface``, UR's Python ``rtde`` module) read it unchanged:

- every package is ``uint16 size`` (header included) + ``uint8 type`` + payload, big-endian;
- ``V`` request protocol version (``uint16``) → ``uint8 accepted`` (version 2 only);
- ``v`` get controller version → four ``uint32`` (major, minor, bugfix, build): an e-Series
  controller, :data:`CONTROLLER_VERSION`;
- ``O`` output setup (``double frequency`` + comma-separated names) → ``uint8 recipe id`` +
  comma-separated types; a name this face does not emulate is ``NOT_FOUND`` and the recipe id
  is then 0 (invalid, as on the controller);
- ``I`` input setup → recipe id + types (input registers and the speed slider; data sent to
  them is accepted and ignored: this face moves the robot on its own schedule);
- ``S`` start / ``P`` pause → ``uint8 accepted``; after start each output recipe streams ``U``
  data packages (``uint8 recipe id`` + values) at its requested frequency (1 … 500 Hz);
- ``M`` text messages from the client are ignored.

What is emulated: the joints (``actual_q``, ``target_q`` [rad], speeds from the motion), the
TCP pose (hook point [m], flange rotation vector [rad]), the controller clock ``timestamp``
[s], and a robot that is powered, running and in normal safety mode. Everything else a client
may ask for (currents, voltages, temperatures, I/O, registers) has its type and a constant
value (0, or nominal: 48 V main voltage, 35 °C joints).

Faults: each data package goes through :meth:`simulator.faces.base.FaceServer.send`: dropped
packages are skipped cycles, a reply delay or a late reply holds the stream (the data is as
old as the delay when it arrives); ``robot_frozen`` freezes the joints; ``link_down`` closes
the port.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import re
import struct
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from simulator.cell import EmulatedCell
from simulator.config import UR_RTDE_PORT, ServerSection
from simulator.faces.base import FaceServer
from simulator.faces.ur_primary import PORT as PRIMARY_PORT
from simulator.faces.ur_primary import UrPrimaryServer

log = logging.getLogger("cablecal.simulator")

# Package types (ASCII letters of the RTDE guide).
REQUEST_PROTOCOL_VERSION = ord("V")
GET_URCONTROL_VERSION = ord("v")
TEXT_MESSAGE = ord("M")
DATA_PACKAGE = ord("U")
SETUP_OUTPUTS = ord("O")
SETUP_INPUTS = ord("I")
START = ord("S")
PAUSE = ord("P")

#: The emulated controller's software version (an e-Series, PolyScope 5.11).
CONTROLLER_VERSION = (5, 11, 0, 108249)
PROTOCOL_VERSION = 2
MAX_FREQUENCY_HZ = 500.0
#: Largest package accepted from a client [bytes] (a recipe of every variable is < 4 kB).
MAX_PACKAGE_BYTES = 16384

#: struct format of each RTDE type.
TYPE_FORMATS = {
    "BOOL": "?",
    "UINT8": "B",
    "UINT32": "I",
    "UINT64": "Q",
    "INT32": "i",
    "DOUBLE": "d",
    "VECTOR3D": "3d",
    "VECTOR6D": "6d",
    "VECTOR6INT32": "6i",
    "VECTOR6UINT32": "6I",
}

_V6 = "VECTOR6D"
#: Output variables with their RTDE types (the RTDE guide's table, PolyScope 5.11).
OUTPUTS: dict[str, str] = {
    "timestamp": "DOUBLE",
    "target_q": _V6,
    "target_qd": _V6,
    "target_qdd": _V6,
    "target_current": _V6,
    "target_moment": _V6,
    "actual_q": _V6,
    "actual_qd": _V6,
    "actual_current": _V6,
    "actual_current_window": _V6,
    "joint_control_output": _V6,
    "actual_TCP_pose": _V6,
    "actual_TCP_speed": _V6,
    "actual_TCP_force": _V6,
    "target_TCP_pose": _V6,
    "target_TCP_speed": _V6,
    "actual_digital_input_bits": "UINT64",
    "joint_temperatures": _V6,
    "actual_execution_time": "DOUBLE",
    "robot_mode": "INT32",
    "joint_mode": "VECTOR6INT32",
    "safety_mode": "INT32",
    "safety_status": "INT32",
    "actual_tool_accelerometer": "VECTOR3D",
    "speed_scaling": "DOUBLE",
    "target_speed_fraction": "DOUBLE",
    "actual_momentum": "DOUBLE",
    "actual_main_voltage": "DOUBLE",
    "actual_robot_voltage": "DOUBLE",
    "actual_robot_current": "DOUBLE",
    "actual_joint_voltage": _V6,
    "actual_digital_output_bits": "UINT64",
    "runtime_state": "UINT32",
    "elbow_position": "VECTOR3D",
    "elbow_velocity": "VECTOR3D",
    "robot_status_bits": "UINT32",
    "safety_status_bits": "UINT32",
    "analog_io_types": "UINT32",
    "standard_analog_input0": "DOUBLE",
    "standard_analog_input1": "DOUBLE",
    "standard_analog_output0": "DOUBLE",
    "standard_analog_output1": "DOUBLE",
    "io_current": "DOUBLE",
    "euromap67_input_bits": "UINT32",
    "euromap67_output_bits": "UINT32",
    "euromap67_24V_voltage": "DOUBLE",
    "euromap67_24V_current": "DOUBLE",
    "tool_mode": "UINT32",
    "tool_analog_input_types": "UINT32",
    "tool_analog_input0": "DOUBLE",
    "tool_analog_input1": "DOUBLE",
    "tool_output_voltage": "INT32",
    "tool_output_current": "DOUBLE",
    "tool_temperature": "DOUBLE",
    "tcp_force_scalar": "DOUBLE",
    "output_bit_registers0_to_31": "UINT32",
    "output_bit_registers32_to_63": "UINT32",
    "input_bit_registers0_to_31": "UINT32",
    "input_bit_registers32_to_63": "UINT32",
    "tool_output_mode": "UINT8",
    "tool_digital_output0_mode": "UINT8",
    "tool_digital_output1_mode": "UINT8",
    "payload": "DOUBLE",
    "payload_cog": "VECTOR3D",
    "payload_inertia": _V6,
    "script_control_line": "UINT32",
    "ft_raw_wrench": _V6,
    "joint_position_deviation_ratio": "DOUBLE",
    "collision_detection_ratio": "DOUBLE",
    "time_scale_source": "UINT32",
}
_REGISTER = re.compile(r"^(output|input)_(int|double|bit)_register_(\d+)$")
_REGISTER_TYPES = {"int": "INT32", "double": "DOUBLE", "bit": "BOOL"}

#: Inputs a client may set up (their data is accepted and ignored).
INPUTS: dict[str, str] = {
    "speed_slider_mask": "UINT32",
    "speed_slider_fraction": "DOUBLE",
    "standard_digital_output_mask": "UINT8",
    "standard_digital_output": "UINT8",
    "configurable_digital_output_mask": "UINT8",
    "configurable_digital_output": "UINT8",
    "tool_digital_output_mask": "UINT8",
    "tool_digital_output": "UINT8",
    "standard_analog_output_mask": "UINT8",
    "standard_analog_output_type": "UINT8",
    "standard_analog_output_0": "DOUBLE",
    "standard_analog_output_1": "DOUBLE",
    "input_bit_registers0_to_31": "UINT32",
    "input_bit_registers32_to_63": "UINT32",
}

#: Constant values of the variables that are not emulated from the motion (others: zero).
CONSTANTS: dict[str, object] = {
    "robot_mode": 7,  # RUNNING
    "joint_mode": (253,) * 6,  # RUNNING
    "safety_mode": 1,  # NORMAL
    "safety_status": 1,
    "runtime_state": 2,  # PLAYING
    "robot_status_bits": 0b11,  # power on, program running
    "safety_status_bits": 0b1,  # normal mode
    "speed_scaling": 1.0,
    "target_speed_fraction": 1.0,
    "actual_main_voltage": 48.0,
    "actual_robot_voltage": 48.0,
    "actual_joint_voltage": (48.0,) * 6,
    "joint_temperatures": (35.0,) * 6,
    "tool_temperature": 35.0,
}


def output_type(name: str) -> str:
    """RTDE type of output variable ``name``, or ``NOT_FOUND``."""
    if name in OUTPUTS:
        return OUTPUTS[name]
    match = _REGISTER.match(name)
    if match and int(match.group(3)) < 48:
        return _REGISTER_TYPES[match.group(2)]
    return "NOT_FOUND"


def input_type(name: str) -> str:
    """RTDE type of input variable ``name``, or ``NOT_FOUND``."""
    if name in INPUTS:
        return INPUTS[name]
    match = _REGISTER.match(name)
    if match and match.group(1) == "input" and match.group(2) != "bit":
        # Registers 0..23 belong to fieldbus adapters on a real controller; all are free here.
        return _REGISTER_TYPES[match.group(2)] if int(match.group(3)) < 48 else "NOT_FOUND"
    return "NOT_FOUND"


def package(kind: int, payload: bytes = b"") -> bytes:
    """One RTDE package: ``uint16 size`` (3 + payload) + ``uint8 type`` + payload."""
    return struct.pack(">HB", 3 + len(payload), kind) + payload


@dataclass
class OutputRecipe:
    """An output recipe of one client."""

    recipe_id: int
    names: list[str]
    types: list[str]
    frequency_hz: float

    @property
    def format(self) -> str:
        return ">B" + "".join(TYPE_FORMATS[t] for t in self.types)


class UrRtdeServer(FaceServer):
    """The EMULATED RTDE port (see the module docstring), and beside it, on the same address,
    the primary interface (:mod:`simulator.faces.ur_primary`, UR's port 30001) when the RTDE
    port is UR's own 30004 (a test's port 0 is any port: no primary interface then)."""

    label = "ur-rtde"
    also_ports = (PRIMARY_PORT,)

    def __init__(self, cell: EmulatedCell, section: ServerSection) -> None:
        super().__init__(cell, section)
        #: Monotonic time [s] of the controller clock's zero (``timestamp`` counts from it).
        self.t0 = time.monotonic()
        self.primary: UrPrimaryServer | None = None

    async def start(self) -> None:
        await super().start()
        if self.port == UR_RTDE_PORT:
            self.primary = UrPrimaryServer(
                self.cell, ServerSection(host=self.host, port=PRIMARY_PORT)
            )
            await self.primary.start()

    async def stop(self) -> None:
        if self.primary is not None:
            await self.primary.stop()
            self.primary = None
        await super().stop()

    # ------------------------------------------------------------------ values
    def values(self, recipe: OutputRecipe, now: float) -> list[object]:
        """The recipe's values at ``now`` (monotonic [s]), flattened for ``struct``."""
        q_deg = self.cell.reported_joints(now)
        q = np.radians(q_deg)
        computed: dict[str, Callable[[], object]] = {
            "timestamp": lambda: now - self.t0,
            "actual_q": lambda: tuple(q),
            "target_q": lambda: tuple(q),
            "actual_qd": lambda: self._speed(now),
            "target_qd": lambda: self._speed(now),
            "actual_TCP_pose": lambda: self._tcp_pose(q_deg),
            "target_TCP_pose": lambda: self._tcp_pose(q_deg),
        }
        out: list[object] = []
        for name, kind in zip(recipe.names, recipe.types, strict=True):
            value = computed[name]() if name in computed else CONSTANTS.get(name)
            if value is None:
                value = zero(kind)
            if isinstance(value, tuple):
                out.extend(value)
            else:
                out.append(value)
        return out

    def _speed(self, now: float) -> tuple[float, ...]:
        dt = 0.004
        q1, q0 = self.cell.reported_joints(now), self.cell.reported_joints(now - dt)
        return tuple(float(v) for v in np.radians(q1 - q0) / dt)

    def _tcp_pose(self, q_deg: np.ndarray) -> tuple[float, ...]:
        x, y, z, a, b, c = self.cell.tcp_pose(q_deg)
        rotvec = Rotation.from_euler("xyz", [a, b, c], degrees=True).as_rotvec()
        return (x / 1000.0, y / 1000.0, z / 1000.0, *map(float, rotvec))

    # ------------------------------------------------------------------ protocol
    async def serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        outputs: dict[int, OutputRecipe] = {}
        inputs: dict[int, list[str]] = {}
        streams: list[asyncio.Task[None]] = []
        version = 0
        try:
            while True:
                head = await reader.readexactly(3)
                size, kind = struct.unpack(">HB", head)
                if not 3 <= size <= MAX_PACKAGE_BYTES:
                    raise ValueError(f"RTDE package size {size} out of range")
                payload = await reader.readexactly(size - 3)
                log.debug("ur-rtde rx %r %s", chr(kind), payload[:80].hex(" "))
                if kind == REQUEST_PROTOCOL_VERSION:
                    (asked,) = struct.unpack(">H", payload[:2])
                    ok = asked == PROTOCOL_VERSION
                    version = asked if ok else version
                    reply = package(kind, struct.pack(">B", ok))
                elif kind == GET_URCONTROL_VERSION:
                    reply = package(kind, struct.pack(">IIII", *CONTROLLER_VERSION))
                elif kind == SETUP_OUTPUTS and version == PROTOCOL_VERSION:
                    reply = self._setup_outputs(payload, outputs, streams)
                elif kind == SETUP_INPUTS and version == PROTOCOL_VERSION:
                    reply = self._setup_inputs(payload, outputs, inputs)
                elif kind == START:
                    ok = bool(outputs) or bool(inputs)
                    if ok and not streams:
                        for recipe in outputs.values():
                            streams.append(asyncio.ensure_future(self._stream(writer, recipe)))
                    reply = package(kind, struct.pack(">B", ok))
                elif kind == PAUSE:
                    await _cancel(streams)
                    reply = package(kind, struct.pack(">B", 1))
                elif kind in (TEXT_MESSAGE, DATA_PACKAGE):
                    continue  # client messages and input data: accepted, not acted upon
                else:
                    reply = package(TEXT_MESSAGE, _text(f"unknown package type {kind}"))
                writer.write(reply)
                await writer.drain()
        finally:
            await _cancel(streams)

    def _setup_outputs(
        self, payload: bytes, outputs: dict[int, OutputRecipe], streams: list[asyncio.Task[None]]
    ) -> bytes:
        (frequency_hz,) = struct.unpack(">d", payload[:8])
        names = _names(payload[8:])
        types = [output_type(n) for n in names]
        valid = (
            "NOT_FOUND" not in types
            and 1.0 <= frequency_hz <= MAX_FREQUENCY_HZ
            and not streams
            and len(outputs) < 254
        )
        recipe_id = 0
        if valid:
            recipe_id = len(outputs) + 1
            outputs[recipe_id] = OutputRecipe(recipe_id, names, types, frequency_hz)
        return package(SETUP_OUTPUTS, struct.pack(">B", recipe_id) + ",".join(types).encode())

    def _setup_inputs(
        self, payload: bytes, outputs: dict[int, OutputRecipe], inputs: dict[int, list[str]]
    ) -> bytes:
        names = _names(payload)
        types = [input_type(n) for n in names]
        recipe_id = 0
        if "NOT_FOUND" not in types:
            recipe_id = len(outputs) + len(inputs) + 1
            inputs[recipe_id] = names
        return package(SETUP_INPUTS, struct.pack(">B", recipe_id) + ",".join(types).encode())

    async def _stream(self, writer: asyncio.StreamWriter, recipe: OutputRecipe) -> None:
        """Data packages of ``recipe`` at its frequency until paused or disconnected."""
        period_s = 1.0 / recipe.frequency_hz
        fmt = recipe.format
        next_t = time.monotonic()
        with contextlib.suppress(ConnectionError):
            while not writer.is_closing():
                now = time.monotonic()
                data = struct.pack(fmt, recipe.recipe_id, *self.values(recipe, now))
                await self.send(writer, package(DATA_PACKAGE, data))
                next_t = max(next_t + period_s, time.monotonic() - period_s)
                await asyncio.sleep(max(0.0, next_t - time.monotonic()))


def _names(payload: bytes) -> list[str]:
    """Variable names of a setup request (ur_rtde ends the list with a comma: ignored)."""
    return [n.strip() for n in payload.decode("ascii", errors="replace").split(",") if n.strip()]


def zero(kind: str) -> object:
    """The zero value of an RTDE type (a tuple for vectors)."""
    fmt = TYPE_FORMATS[kind]
    n = int(fmt[0]) if fmt[0].isdigit() else 1
    base: object = 0.0 if fmt[-1] == "d" else (False if fmt == "?" else 0)
    return (base,) * n if n > 1 else base


def _text(message: str) -> bytes:
    """Payload of a version-2 text message: message, source, warning level (2 = info)."""
    m, s = message.encode()[:255], b"cablecal-emulated-rtde"
    return struct.pack(">B", len(m)) + m + struct.pack(">B", len(s)) + s + struct.pack(">B", 2)


async def _cancel(tasks: list[asyncio.Task[None]]) -> None:
    for task in tasks:
        task.cancel()
    for task in tasks:
        with contextlib.suppress(asyncio.CancelledError, Exception):
            await task
    tasks.clear()


__all__ = ["OUTPUTS", "UrRtdeServer"]
