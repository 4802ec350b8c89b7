"""The emulated cell's ground truth: robot motion, cable length, indicator state, faults.

Shape of ophyd's ``SynGauss``: the indicator's reading is computed from the emulated robot's
current (interpolated) joint angles through :class:`calib.synthetic.TrueCell`, with seeded
noise and quantisation to the indicator's decimals. Nothing here does I/O.
"""

from __future__ import annotations

import math
import re
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from calib.kinematics import FloatArray, forward_frames
from calib.models import RobotModel, builtin_model, parse_model_text
from calib.synthetic import TABLE_XII_D1, TrueCell, make_true_cell
from simulator.config import (
    MAX_ANCHOR_MOVE_MM,
    MAX_DRIFT_RATE_MM_PER_H,
    MAX_DRIFT_TAU_S,
    SimConfig,
)
from simulator.poses import PoseCsvError, parse_poses_file, spread_poses_deg

#: Largest poses file the control port reads [bytes] (a 2000-pose plan CSV is about 150 kB).
MAX_POSES_FILE_BYTES = 8 * 1024 * 1024
#: Where a program's error is: its line, or a target and joint (no text of the file).
_PROGRAM_WHERE = re.compile(r"\bline \d+|\btarget \d+(, q\d)?")

#: Display limits of the 6-digit indicator (counts).
DISPLAY_MIN, DISPLAY_MAX = -199999, 999999
#: Sensor resolution [mm/pulse] (HY150-2000).
MM_PER_PULSE = 0.004

STATUS_OVER, STATUS_UNDER, STATUS_MOVING = 0, 1, 2
#: Column of the joint offset (theta error, rad internally) in a joint's 4 DH errors.
DH_THETA_COLUMN = 3


def _finite_number(value: Any, name: str, bound: float, low: float | None = None) -> float:
    """``value`` as a float, or ``ValueError`` naming ``name``: not a number, not finite, or
    outside ``[low, bound]`` (``low`` default ``-bound``)."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ValueError(f"{name}: expected a number, got {value!r}")
    v = float(value)
    lo = -bound if low is None else low
    if not math.isfinite(v) or not lo <= v <= bound:
        raise ValueError(f"{name}: {value!r} is not finite or outside [{lo:g}, {bound:g}]")
    return v


@dataclass(frozen=True)
class OffsetDrift:
    """An emulated drift of the indicator offset c, started at monotonic ``t0`` [s].

    Linear at ``rate_mm_per_h`` when ``tau_s`` is 0, else a first-order approach to
    ``rate_mm_per_h * tau_s / 3600`` mm with time constant ``tau_s`` (same initial slope)."""

    rate_mm_per_h: float = 0.0
    tau_s: float = 0.0
    t0: float = 0.0

    def mm(self, now: float) -> float:
        """The drift at monotonic ``now`` [mm]."""
        dt = max(0.0, now - self.t0)
        rate_mm_per_s = self.rate_mm_per_h / 3600.0
        if self.tau_s > 0:
            return rate_mm_per_s * self.tau_s * -math.expm1(-dt / self.tau_s)
        return rate_mm_per_s * dt


@dataclass
class Faults:
    """Switchable faults (see :class:`simulator.config.FaultSection`)."""

    indicator_crc_error_rate: float = 0.0
    indicator_drop_rate: float = 0.0
    indicator_reply_delay_s: float = 0.0
    over_range: bool = False
    robot_drop_rate: float = 0.0
    robot_reply_delay_s: float = 0.0
    robot_late_rate: float = 0.0
    robot_late_delay_s: float = 0.3
    robot_frozen: bool = False

    def update(self, changes: dict[str, Any]) -> None:
        """Set the given fields; unknown names raise ``ValueError``."""
        for key, value in changes.items():
            if not hasattr(self, key):
                raise ValueError(f"unknown fault {key!r}; known: {sorted(asdict(self))}")
            current = getattr(self, key)
            setattr(self, key, bool(value) if isinstance(current, bool) else float(value))


def load_model(name_or_path: str, base_dir: str) -> RobotModel:
    """A built-in model by name, or a ``.toml``/``.json`` model file."""
    if name_or_path.endswith((".toml", ".json")):
        path = Path(base_dir) / name_or_path
        return parse_model_text(path.read_text(encoding="utf-8"), path.suffix[1:])
    return builtin_model(name_or_path)


def _smoothstep(s: float) -> float:
    """Quintic 0→1 with zero velocity and acceleration at both ends."""
    return s * s * s * (10.0 + s * (-15.0 + 6.0 * s))


def rpy_deg(rot: FloatArray) -> tuple[float, float, float]:
    """Fixed-axis X-Y-Z angles (A about X, B about Y, C about Z) [deg] of a rotation matrix."""
    b = math.asin(max(-1.0, min(1.0, -float(rot[2, 0]))))
    a = math.atan2(float(rot[2, 1]), float(rot[2, 2]))
    c = math.atan2(float(rot[1, 0]), float(rot[0, 0]))
    return math.degrees(a), math.degrees(b), math.degrees(c)


@dataclass
class EmulatedCell:
    """Truth and state of the emulated cell. Times are :func:`time.monotonic` seconds.

    Motion: dwell ``dwell_s`` at pose 0, move to pose 1 in ``move_time_s`` (quintic profile),
    dwell, …; after the last pose it moves back to pose 0 when ``loop``.
    """

    config: SimConfig
    truth: TrueCell = field(init=False)
    poses_deg: FloatArray = field(init=False)
    faults: Faults = field(init=False)

    def __post_init__(self) -> None:
        cfg = self.config
        model = load_model(cfg.robot.model, cfg.base_dir)
        errors = TABLE_XII_D1 if cfg.robot.dh_errors == "table-xii-d1" else np.zeros((6, 4))
        self.truth = make_true_cell(
            model,
            dh_errors_deg_mm=errors,
            tool_error_mm=np.array(cfg.robot.tool_error_mm),
            anchors_mm=np.array([cfg.cell.anchor_mm]),
            offsets_mm=np.array([cfg.cell.offset_mm]),
        )
        rng = np.random.default_rng(cfg.seed)
        self.loop = cfg.robot.loop
        self._approach_from: FloatArray | None = None
        if cfg.robot.poses == "random":
            self.poses_deg = spread_poses_deg(
                self.truth, cfg.robot.n_poses, rng, min_z_mm=cfg.robot.min_z_mm
            )
        else:
            self.poses_deg = self.read_poses_csv(cfg.robot.poses)
        self._noise_rng = np.random.default_rng([cfg.seed, 1])
        self.fault_rng = np.random.default_rng([cfg.seed, 2])
        self.faults = Faults(**cfg.faults.model_dump())
        self._t0 = time.monotonic()
        self._held_at: float | None = None
        self._held_total = 0.0
        self._frozen_joints: FloatArray | None = None
        self._tick = -1
        self._tick_length = 0.0
        self.decimals = cfg.indicator.decimals
        self.preset_counts = 0
        self.slave_address = cfg.indicator.device_id
        self.baud_code = 0
        self._drift_base_mm = 0.0  # drift of earlier drift_offset segments, folded in
        self.drift = OffsetDrift(cfg.cell.drift_rate_mm_per_h, cfg.cell.drift_tau_s, self._t0)

    # ------------------------------------------------------------------ motion
    def _virtual_time(self, now: float) -> float:
        held = self._held_total + (now - self._held_at if self._held_at is not None else 0.0)
        return now - self._t0 - held

    def hold(self, on: bool, now: float | None = None) -> None:
        """Stop (``True``) or resume (``False``) the motion schedule."""
        now = time.monotonic() if now is None else now
        if on and self._held_at is None:
            self._held_at = now
        elif not on and self._held_at is not None:
            self._held_total += now - self._held_at
            self._held_at = None

    def motion(self, now: float | None = None) -> tuple[FloatArray, int, bool]:
        """``(joints_deg (6,), pose_index, moving)`` at ``now``.

        After :meth:`load_poses` the robot first moves from where it was to the new pose 0
        (``move_time_s``, reported as pose 0 and moving), then follows the usual schedule.
        """
        now = time.monotonic() if now is None else now
        t = max(0.0, self._virtual_time(now))
        n = self.poses_deg.shape[0]
        dwell, move = self.config.robot.dwell_s, self.config.robot.move_time_s
        if self._approach_from is not None:
            if t < move:
                s = _smoothstep(t / move)
                return self._approach_from + s * (self.poses_deg[0] - self._approach_from), 0, True
            t -= move
        period = dwell + move
        k = int(t // period)
        phase = t - k * period
        if not self.loop and k >= n - 1:
            return self.poses_deg[n - 1].copy(), n - 1, False
        i = k % n
        if phase < dwell or n == 1:
            return self.poses_deg[i].copy(), i, False
        s = _smoothstep((phase - dwell) / move)
        q = self.poses_deg[i] + s * (self.poses_deg[(i + 1) % n] - self.poses_deg[i])
        return q, i, True

    def read_poses_csv(self, path: str) -> FloatArray:
        """Joint angles [deg], shape (n, 6), of a plan CSV (``q1..q6`` columns) or a robot
        program (RAPID, URScript, KRL, Fanuc LS: its joint moves; see :mod:`simulator.poses`),
        checked against the model's joint limits. A relative path is resolved against the
        config's ``base_dir``."""
        full = Path(self.config.base_dir) / path
        try:
            text = full.read_text(encoding="utf-8")
        except OSError as exc:
            raise ValueError(f"robot.poses: cannot read {full}: {exc.strerror}") from None
        return parse_poses_file(text, str(full), self.truth.model.limits_deg())

    def parse_poses_text(self, text: str, source: str) -> FloatArray:
        """Joint angles [deg], shape (n, 6), of a plan CSV's or robot program's text, checked
        against the joint limits; errors name ``source``."""
        return parse_poses_file(text, source, self.truth.model.limits_deg())

    def confined_path(self, path: str) -> Path:
        """``path`` (relative or absolute) resolved, symlinks and ``..`` included, and checked
        to be a regular file inside the config's ``base_dir`` of at most
        :data:`MAX_POSES_FILE_BYTES` (the control port reads nothing else).

        Raises ``ValueError`` naming ``path`` as given, never anything read from it.
        """
        base = Path(self.config.base_dir).resolve()
        full = (base / path).resolve()
        if not full.is_relative_to(base):
            raise ValueError(f"{path}: outside the cell's config directory {base}")
        if not full.is_file():
            raise ValueError(f"{path}: no such file in the cell's config directory {base}")
        if full.stat().st_size > MAX_POSES_FILE_BYTES:
            raise ValueError(f"{path}: larger than {MAX_POSES_FILE_BYTES} bytes")
        return full

    def read_confined_poses(self, path: str) -> FloatArray:
        """Joint angles [deg], shape (n, 6), of a plan CSV or robot program at ``path`` inside
        the config's directory (:meth:`confined_path`), for the control port: an error names
        the file and where in it (row, column, target), never its contents."""
        full = self.confined_path(path)
        try:
            text = full.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError):
            raise ValueError(f"{path}: not a valid poses file (not UTF-8 text)") from None
        try:
            return parse_poses_file(text, path, self.truth.model.limits_deg())
        except PoseCsvError as exc:
            where = [f"row {exc.row}"] if exc.row is not None else []
            where += [f"column {exc.column!r}"] if exc.column is not None else []
            if not where and (found := _PROGRAM_WHERE.search(str(exc))):
                where = [found.group(0)]
            detail = f" ({', '.join(where)})" if where else ""
            raise ValueError(f"{path}: not a valid poses file{detail}") from None

    def load_poses(
        self, poses_deg: FloatArray, loop: bool | None = None, now: float | None = None
    ) -> None:
        """Follow a new pose list ``(n, 6)`` [deg] from its first pose: the robot moves there
        from where it is (``move_time_s``), dwells, and goes on with the usual schedule.
        ``loop`` (default: unchanged) repeats the list. A hold stays in force.

        Raises ``ValueError`` naming the row (1-based) and joint for a bad shape, a
        non-finite value or a value outside the joint limits.
        """
        now = time.monotonic() if now is None else now
        q = np.asarray(poses_deg, dtype=float)
        if q.ndim != 2 or q.shape[1] != 6 or q.shape[0] == 0:
            raise ValueError(f"poses_deg: expected shape (n, 6) with n >= 1, got {q.shape}")
        limits = self.truth.model.limits_deg()
        bad = ~np.isfinite(q) | (q < limits[:, 0]) | (q > limits[:, 1])
        if bad.any():
            row, j = (int(v) for v in np.argwhere(bad)[0])
            raise ValueError(
                f"poses_deg row {row + 1}, q{j + 1}: {q[row, j]} deg is not finite or outside "
                f"the joint limits [{limits[j, 0]}, {limits[j, 1]}] deg"
            )
        current, _, _ = self.motion(now)
        self.poses_deg = q.copy()
        self._approach_from = None if np.allclose(current, q[0]) else current
        if loop is not None:
            self.loop = loop
        self._t0 = now
        self._held_total = 0.0
        if self._held_at is not None:
            self._held_at = now
        self._tick = -1

    def reported_joints(self, now: float | None = None) -> FloatArray:
        """Joint angles the emulated controller reports (stale while ``robot_frozen``)."""
        q, _, _ = self.motion(now)
        if self.faults.robot_frozen:
            if self._frozen_joints is None:
                self._frozen_joints = q
            return self._frozen_joints.copy()
        self._frozen_joints = None
        return q

    def tcp_pose(self, q_deg: FloatArray) -> tuple[float, ...]:
        """True X, Y, Z [mm] of the hook point and A, B, C [deg] of the flange."""
        dh = self.truth.model.dh_internal() + self.truth.theta[:24].reshape(6, 4)
        rot, _ = forward_frames(
            dh, self.truth.model.table_rad(q_deg[None, :]), self.truth.model.convention
        )
        xyz = self.truth.tool_positions_mm(q_deg)[0]
        return (*map(float, xyz), *rpy_deg(rot[0, 6]))

    # ------------------------------------------------------------------ cable
    @property
    def offset_mm(self) -> float:
        return float(self.truth.theta[self.truth.layout.anchor_slice(0)][3])

    @property
    def anchor_mm(self) -> FloatArray:
        return self.truth.theta[self.truth.layout.anchor_slice(0)][:3].copy()

    def _set_offset(self, offset_mm: float) -> None:
        theta = self.truth.theta.copy()
        theta[self.truth.layout.anchor_slice(0).start + 3] = offset_mm
        self.truth = TrueCell(self.truth.model, theta, self.truth.layout)

    def drift_mm(self, now: float | None = None) -> float:
        """The emulated offset drift at ``now`` [mm]: added to every reading on top of the
        offset c of the truth."""
        now = time.monotonic() if now is None else now
        return self._drift_base_mm + self.drift.mm(now)

    def true_lengths_mm(self, q_deg: FloatArray, now: float | None = None) -> FloatArray:
        """Noise-free cable readings, shape (n,) [mm], of poses ``(n, 6)`` [deg] at ``now``
        (with the offset drift)."""
        return self.truth.lengths_mm(q_deg) + self.drift_mm(now)

    def true_length_mm(self, now: float | None = None) -> float:
        """Noise-free cable reading of the current pose [mm]."""
        now = time.monotonic() if now is None else now
        q, _, _ = self.motion(now)
        return float(self.true_lengths_mm(q[None, :], now)[0])

    def move_anchor(self, delta_mm: Any) -> FloatArray:
        """Disturbance emulation: the sensor stand is bumped, the TRUE P0 moves by
        ``delta_mm`` (3 numbers [mm], each within ±:data:`MAX_ANCHOR_MOVE_MM`). Returns the
        new P0 [mm], shape (3,). ``ValueError`` naming ``delta_mm`` on bad input (nothing
        changes)."""
        if not isinstance(delta_mm, list | tuple) or len(delta_mm) != 3:
            raise ValueError(f"delta_mm: expected a list of 3 numbers [mm], got {delta_mm!r}")
        delta = [
            _finite_number(v, f"delta_mm[{i}]", MAX_ANCHOR_MOVE_MM) for i, v in enumerate(delta_mm)
        ]
        theta = self.truth.theta.copy()
        start = self.truth.layout.anchor_slice(0).start
        theta[start : start + 3] += delta
        self.truth = TrueCell(self.truth.model, theta, self.truth.layout)
        self._tick = -1  # resample
        return self.anchor_mm

    def drift_offset(self, rate_mm_per_h: Any, tau_s: Any = 0.0, now: float | None = None) -> None:
        """Disturbance emulation: from ``now`` the offset drifts at ``rate_mm_per_h``
        (linear), or with ``tau_s`` > 0 approaches ``rate_mm_per_h * tau_s / 3600`` mm
        (first order). The drift so far is kept; a rate of 0 stops it. ``ValueError`` naming
        the field on bad input (nothing changes)."""
        rate = _finite_number(rate_mm_per_h, "rate_mm_per_h", MAX_DRIFT_RATE_MM_PER_H)
        tau = _finite_number(0.0 if tau_s is None else tau_s, "tau_s", MAX_DRIFT_TAU_S, 0.0)
        now = time.monotonic() if now is None else now
        self._drift_base_mm = self.drift_mm(now)
        self.drift = OffsetDrift(rate, tau, now)
        self._tick = -1

    def indicator_state(self, now: float | None = None) -> tuple[int, int, float]:
        """``(counts, status, noisy_length_mm)``: the display value, sampled and held at
        ``update_hz`` (seeded noise, rounded to the decimals), and the status bits."""
        now = time.monotonic() if now is None else now
        ind = self.config.indicator
        tick = int(self._virtual_time(now) * ind.update_hz)
        if tick != self._tick:
            noise = self._noise_rng.normal(0.0, ind.noise_mm) if ind.noise_mm > 0 else 0.0
            self._tick_length = self.true_length_mm(now) + noise
            self._tick = tick
        _, _, moving = self.motion(now)
        length = self._tick_length
        lo, hi = ind.range_mm
        status = (1 << STATUS_MOVING) if moving else 0
        if self.faults.over_range or length > hi:
            status |= 1 << STATUS_OVER
            length = hi
        elif length < lo:
            status |= 1 << STATUS_UNDER
            length = lo
        counts = round(length * 10**self.decimals)
        return max(DISPLAY_MIN, min(DISPLAY_MAX, counts)), status, length

    def zero(self, now: float | None = None) -> None:
        """Zero command: the current noise-free length becomes 0."""
        self.set_display_mm(0.0, now)

    def set_display_mm(self, value_mm: float, now: float | None = None) -> None:
        """Preset: the display reads ``value_mm`` at the current pose (changes offset c)."""
        current = self.true_length_mm(now)
        self._set_offset(self.offset_mm + value_mm - current)
        self._tick = -1  # resample

    def shift_joint_offset(self, joint: int, delta_deg: float) -> float:
        """Robot-change emulation (a hold check then fails): add ``delta_deg`` to the TRUE
        joint offset (DH theta error) of ``joint`` (1..6). The controller keeps reporting the
        same joint angles; the cable length and the true TCP follow the new truth. Returns the
        joint's new offset [deg]."""
        if not 1 <= joint <= 6:
            raise ValueError(f"joint: expected 1..6, got {joint}")
        if not math.isfinite(delta_deg):
            raise ValueError(f"delta_deg: not finite: {delta_deg}")
        index = (joint - 1) * 4 + DH_THETA_COLUMN
        theta = self.truth.theta.copy()
        theta[index] += math.radians(delta_deg)
        self.truth = TrueCell(self.truth.model, theta, self.truth.layout)
        self._tick = -1  # resample
        return math.degrees(float(theta[index]))

    def magnification_x1000(self) -> int:
        """Pulses → counts factor ×1000 (0.400 for two decimals)."""
        return int(MM_PER_PULSE * 1000 * 10**self.decimals + 0.5)

    # ------------------------------------------------------------------ reports
    def truth_report(self) -> dict[str, Any]:
        """The ``truth`` control reply."""
        layout = self.truth.layout
        values = self.truth.theta * layout.display_scale
        return {
            "model": self.truth.model.name,
            "names": list(layout.names),
            "units": list(layout.units),
            "values": [float(v) for v in values],
            "joint_offsets_deg": [
                math.degrees(float(v)) for v in self.truth.theta[DH_THETA_COLUMN : 4 * 6 : 4]
            ],
            "anchor_p0_mm": [float(v) for v in self.anchor_mm],
            "offset_mm": self.offset_mm + self.drift_mm(),
            "drift": {
                "rate_mm_per_h": self.drift.rate_mm_per_h,
                "tau_s": self.drift.tau_s,
                "drift_mm": self.drift_mm(),
                "offset_base_mm": self.offset_mm,
            },
            "noise_mm": self.config.indicator.noise_mm,
            "decimals": self.decimals,
            "range_mm": list(self.config.indicator.range_mm),
        }

    def state_report(self, now: float | None = None) -> dict[str, Any]:
        """The ``state`` control reply."""
        now = time.monotonic() if now is None else now
        q, i, moving = self.motion(now)
        return {
            "pose_index": i,
            "n_poses": int(self.poses_deg.shape[0]),
            "loop": self.loop,
            "moving": moving,
            "held": self._held_at is not None,
            "joints_deg": [float(v) for v in q],
            "true_length_mm": self.true_length_mm(now),
            "t_s": self._virtual_time(now),
            "faults": asdict(self.faults),
        }
