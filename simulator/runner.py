"""Assemble the emulated cell: servers, control port, the ``READY`` line.

:class:`CellRunner` runs on the caller's asyncio loop (``cablecal simulate``);
:class:`SimulatorThread` runs one in a background thread for tests and benchmarks.

Control protocol (loopback TCP, one JSON object per line each way): see :meth:`CellRunner.command`.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import shutil
import signal
import socket
import sys
import tempfile
import threading
from dataclasses import asdict
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np

from simulator.cell import MAX_POSES_FILE_BYTES, EmulatedCell
from simulator.config import ServerSection, SimConfig
from simulator.faces import FACE_READY_KEYS, FACES, FaceServer
from simulator.servers import (
    HuashuSocketCmdServer,
    PtyIndicator,
    TcpIndicator,
    TcpServer,
    UrModbusServer,
)

READY_KEYS = (
    "indicator_port",
    "indicator_tcp",
    "robot_socketcmd",
    "robot_modbus",
    *FACE_READY_KEYS,
    "control",
)


class CellRunner:
    """The whole emulated cell on one asyncio loop."""

    def __init__(self, config: SimConfig, workdir: Path | None = None) -> None:
        self.config = config
        self.cell = EmulatedCell(config)
        self._own_dir = workdir is None
        self.workdir = (
            Path(tempfile.mkdtemp(prefix="cablecal-sim-")) if workdir is None else workdir
        )
        self.pty: PtyIndicator | None = None
        self.indicator_tcp: TcpIndicator | None = None
        self.socketcmd: HuashuSocketCmdServer | None = None
        self.modbus: UrModbusServer | None = None
        #: The running controller faces by READY key (:data:`simulator.faces.FACES`).
        self.faces: dict[str, FaceServer] = {}
        self._control_server: asyncio.Server | None = None
        self._control_port = 0
        self._tasks: set[asyncio.Task[None]] = set()
        self.stopped = asyncio.Event()

    async def start(self) -> dict[str, str | None]:
        """Start every enabled endpoint; returns the READY mapping."""
        cfg = self.config
        ind = cfg.indicator
        if ind.pty:
            self.pty = PtyIndicator(self.cell, self.workdir / "indicator")
            await self.pty.start()
        if ind.tcp != "none":
            self.indicator_tcp = TcpIndicator(self.cell, ind.tcp_host, ind.tcp_port, ind.tcp)
            await self.indicator_tcp.start()
        if cfg.robot_socketcmd.enabled:
            s = cfg.robot_socketcmd
            self.socketcmd = HuashuSocketCmdServer(self.cell, s.host, s.port)
            await self.socketcmd.start()
        if cfg.robot_modbus.enabled:
            s = cfg.robot_modbus
            self.modbus = UrModbusServer(self.cell, s.host, s.port)
            await self.modbus.start()
        for face in FACES.values():
            section = getattr(cfg, face.table)
            assert isinstance(section, ServerSection)
            if section.enabled:
                server = face.server(self.cell, section)
                await server.start()
                self.faces[face.ready_key] = server
        if cfg.control.enabled:
            self._control_server = await asyncio.start_server(
                self._control_client,
                cfg.control.host,
                cfg.control.port,
                reuse_address=True,
                limit=2 * MAX_POSES_FILE_BYTES,  # a line may carry a program's text
            )
            self._control_port = self._control_server.sockets[0].getsockname()[1]
        return self.ready()

    def ready(self) -> dict[str, str | None]:
        """Endpoints: ``indicator_port`` (pty symlink path), ``indicator_tcp``,
        ``robot_socketcmd``, ``robot_modbus``, the controller faces ``robot_abb_rws``,
        ``robot_ur_rtde``, ``robot_kuka_varproxy``, ``robot_fanuc_rmi`` and ``control``
        (``host:port``, or None when disabled or not emulated)."""
        faces = {
            key: self.faces[key].endpoint if key in self.faces else None for key in FACE_READY_KEYS
        }
        return {
            "indicator_port": str(self.pty.link_path) if self.pty else None,
            "indicator_tcp": self.indicator_tcp.endpoint if self.indicator_tcp else None,
            "robot_socketcmd": self.socketcmd.endpoint if self.socketcmd else None,
            "robot_modbus": self.modbus.endpoint if self.modbus else None,
            **faces,
            "control": (
                f"{self.config.control.host}:{self._control_port}" if self._control_server else None
            ),
        }

    def ports(self) -> dict[str, int]:
        """The TCP ports actually bound (after :meth:`start`), by READY key: those set to 0 in
        the config show the free port the OS chose. Disabled endpoints are absent."""
        out: dict[str, int] = {}
        for key, value in self.ready().items():
            if key != "indicator_port" and value is not None:
                out[key] = int(value.rsplit(":", 1)[1])
        return out

    def summary(self) -> str:
        """One human-readable line with every endpoint (printed on start)."""
        ready = self.ready()
        parts = [f"{key} {value}" for key, value in ready.items() if value is not None]
        return "EMULATED cell endpoints: " + ", ".join(parts)

    async def stop(self) -> None:
        """Stop every endpoint and remove the work directory."""
        for task in list(self._tasks):
            task.cancel()
        if self._control_server is not None:
            self._control_server.close()
            self._control_server = None
        servers: list[TcpServer | None] = [self.indicator_tcp, self.socketcmd, self.modbus]
        servers += self.faces.values()
        for server in servers:
            if server is not None:
                await server.stop()
        if self.pty is not None:
            await self.pty.stop()
        if self._own_dir:
            shutil.rmtree(self.workdir, ignore_errors=True)
        self.stopped.set()

    def _spawn(self, coro: Any) -> None:
        task: asyncio.Task[None] = asyncio.ensure_future(coro)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    # ------------------------------------------------------------------ control
    async def _control_client(
        self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter
    ) -> None:
        try:
            while line := await reader.readline():
                try:
                    request = json.loads(line)
                    if not isinstance(request, dict):
                        raise ValueError("expected a JSON object")
                    reply = {"ok": True, **(await self.command(request))}
                except Exception as exc:  # reported to the client, the cell keeps running
                    reply = {"ok": False, "error": f"{type(exc).__name__}: {exc}"}
                writer.write(json.dumps(reply).encode() + b"\n")
                await writer.drain()
        except ConnectionError:
            pass
        finally:
            writer.close()

    async def command(self, request: dict[str, Any]) -> dict[str, Any]:
        """Execute one control command. (Over 80 lines because this docstring is the control
        port's reference; the dispatch itself is short.)

        Commands (``cmd``):

        ``ping``
            ``{}``.
        ``ready``
            The READY mapping under ``"ready"``.
        ``truth``
            True parameter names, units, values (deg, mm), ``anchor_p0_mm``, ``offset_mm``,
            ``noise_mm``, ``decimals``, ``range_mm``.
        ``true_lengths``
            ``joints_deg``: list of 6-lists → ``lengths_mm``, noise-free.
        ``state``
            ``pose_index``, ``n_poses``, ``moving``, ``held``, ``joints_deg``,
            ``true_length_mm``, ``t_s``, ``faults``.
        ``poses``
            The pose list (``poses_deg``) and ``loop``.
        ``load_poses``
            Follow a new pose list: ``poses_deg`` (list of 6-lists [deg]), ``csv`` (path of a
            plan CSV with ``q1..q6`` columns) or ``program`` (path of a robot program in any
            format of ``cablecal program``: the robot runs its joint moves; a CSV is read as
            with ``csv``), or ``text`` (a program's or plan CSV's text); optional
            ``loop``. The robot moves from where it is to the new pose 0, then dwells and
            moves as usual. Replies like ``poses``. A path must lead, after symlinks and
            ``..``, to a file inside the config's directory; an error names where in the file
            it is, never what the file holds.
        ``shift_joint_offset``
            Robot-change emulation: ``joint`` (1..6), ``delta_deg``: the TRUE joint offset moves by
            ``delta_deg`` (the controller reports the same angles; the lengths change).
            Replies ``joint``, ``joint_offset_deg`` (the new true offset) and the ``truth``
            reply under ``truth``.
        ``move_anchor``
            Disturbance emulation: ``delta_mm`` ([x, y, z] mm): the sensor stand is bumped,
            the TRUE P0 moves. Replies ``anchor_p0_mm`` and the ``truth`` reply.
        ``drift_offset``
            Disturbance emulation: ``rate_mm_per_h``, optional ``tau_s``: the offset c
            drifts linearly, or approaches ``rate * tau`` (first order). Replies the
            ``truth`` reply (its ``drift`` block).
        ``hold``
            ``on``: true stops the motion schedule where it is (false resumes).
        ``fault``
            Any fault fields (``indicator_crc_error_rate``, ``indicator_drop_rate``,
            ``indicator_reply_delay_s``, ``over_range``, ``robot_drop_rate``,
            ``robot_reply_delay_s``, ``robot_late_rate``, ``robot_late_delay_s``,
            ``robot_frozen``); ``clear: true`` resets all first.
        ``link_down``
            ``target`` (``indicator``, ``indicator_tcp``, ``robot_socketcmd``,
            ``robot_modbus``, a face's READY key such as ``robot_ur_rtde``, or ``all``),
            ``duration_s``: the endpoint goes away and comes
            back at the same address. Returns at once.
        ``alarm``
            ``code``, ``text``: unsolicited ``i:-1`` frame to SocketCmd clients.
        ``stop``
            Stop the cell.
        """
        cmd = request.get("cmd")
        cell = self.cell
        if cmd == "ping":
            return {}
        if cmd == "ready":
            return {"ready": self.ready()}
        if cmd == "truth":
            return cell.truth_report()
        if cmd == "true_lengths":
            q = np.asarray(request["joints_deg"], dtype=float).reshape(-1, 6)
            return {"lengths_mm": [float(v) for v in cell.true_lengths_mm(q)]}
        if cmd == "state":
            return cell.state_report()
        if cmd == "poses":
            return {"poses_deg": cell.poses_deg.tolist(), "loop": cell.loop}
        if cmd == "load_poses":
            return self._load_poses(request)
        if cmd == "shift_joint_offset":
            joint = request.get("joint")
            if not isinstance(joint, int) or isinstance(joint, bool):
                raise ValueError(f"joint: expected an integer 1..6, got {joint!r}")
            new_deg = cell.shift_joint_offset(joint, float(request["delta_deg"]))
            return {"joint": joint, "joint_offset_deg": new_deg, "truth": cell.truth_report()}
        if cmd == "move_anchor":
            p0 = cell.move_anchor(request.get("delta_mm"))
            return {"anchor_p0_mm": [float(v) for v in p0], "truth": cell.truth_report()}
        if cmd == "drift_offset":
            if "rate_mm_per_h" not in request:
                raise ValueError("rate_mm_per_h: required (mm/h; 0 stops the drift)")
            cell.drift_offset(request["rate_mm_per_h"], request.get("tau_s", 0.0))
            return {"truth": cell.truth_report()}
        if cmd == "hold":
            cell.hold(bool(request.get("on", True)))
            return cell.state_report()
        if cmd == "fault":
            changes = {k: v for k, v in request.items() if k not in ("cmd", "clear")}
            if request.get("clear"):
                cell.faults = type(cell.faults)()
            cell.faults.update(changes)
            return {"faults": asdict(cell.faults)}
        if cmd == "link_down":
            duration = float(request.get("duration_s", 1.0))
            target = request.get("target", "all")
            targets: dict[str, Any] = {
                "indicator": self.pty,
                "indicator_tcp": self.indicator_tcp,
                "robot_socketcmd": self.socketcmd,
                "robot_modbus": self.modbus,
                **{key: self.faces.get(key) for key in FACE_READY_KEYS},
            }
            names = list(targets) if target == "all" else [target]
            for name in names:
                if name not in targets:
                    raise ValueError(f"unknown target {name!r}; known: {sorted(targets)}")
                if targets[name] is not None:
                    self._spawn(targets[name].link_down(duration))
            await asyncio.sleep(0.05)  # let the endpoints go down before replying
            return {"down": names, "duration_s": duration}
        if cmd == "alarm":
            if self.socketcmd is None:
                raise ValueError("robot_socketcmd is disabled")
            sent = await self.socketcmd.alarm(int(request.get("code", 1)), str(request["text"]))
            return {"clients": sent}
        if cmd == "stop":
            asyncio.get_running_loop().call_soon(self._spawn, self.stop())
            return {}
        raise ValueError(f"unknown cmd {cmd!r}")

    def _load_poses(self, request: dict[str, Any]) -> dict[str, Any]:
        """The ``load_poses`` command."""
        cell = self.cell
        given = [k for k in ("csv", "program", "text", "poses_deg") if k in request]
        if len(given) != 1:
            raise ValueError(
                "load_poses: give exactly one of 'csv' (a path), 'program' (a path), 'text' "
                "(a program or plan CSV) or 'poses_deg'"
            )
        if given[0] in ("csv", "program"):
            poses = cell.read_confined_poses(str(request[given[0]]))
        elif given[0] == "text":
            text = request["text"]
            if not isinstance(text, str):
                raise ValueError("text: expected the program or plan CSV as a string")
            poses = cell.parse_poses_text(text, "text")
        else:
            poses = np.asarray(request["poses_deg"], dtype=float)
        loop = request.get("loop")
        cell.load_poses(poses, loop=None if loop is None else bool(loop))
        return {"poses_deg": cell.poses_deg.tolist(), "loop": cell.loop}


async def serve_forever(config: SimConfig, out: Any = None, err: Any = None) -> None:
    """Run the cell until SIGINT/SIGTERM or a ``stop`` command; print ``READY {json}`` (the
    bound endpoints) on ``out`` and the same as a human-readable line on ``err``."""
    out = sys.stdout if out is None else out
    err = sys.stderr if err is None else err
    runner = CellRunner(config)
    ready = await runner.start()
    err.write(runner.summary() + "\n")
    err.flush()
    out.write("READY " + json.dumps(ready) + "\n")
    out.flush()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, lambda: runner._spawn(runner.stop()))
    try:
        await runner.stopped.wait()
    finally:
        if not runner.stopped.is_set():
            await runner.stop()


class ControlClient:
    """Blocking JSON-lines client of the control port (for tests and scripts)."""

    def __init__(self, endpoint: str, timeout_s: float = 5.0) -> None:
        host, port = endpoint.rsplit(":", 1)
        self._sock = socket.create_connection((host, int(port)), timeout=timeout_s)
        self._file = self._sock.makefile("rwb")

    def __call__(self, cmd: str, **fields: Any) -> dict[str, Any]:
        """Send ``{"cmd": cmd, **fields}``; return the reply, raising on ``ok: false``."""
        self._file.write(json.dumps({"cmd": cmd, **fields}).encode() + b"\n")
        self._file.flush()
        line = self._file.readline()
        if not line:
            raise ConnectionError("control port closed")
        reply: dict[str, Any] = json.loads(line)
        if not reply.get("ok"):
            raise RuntimeError(reply.get("error", "control command failed"))
        return reply

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self._file.close()
            self._sock.close()


class SimulatorThread:
    """An emulated cell on its own event loop in a daemon thread.

    Use as a context manager::

        with SimulatorThread(config) as sim:
            sim.ready["indicator_port"]; sim.control("state")
    """

    def __init__(self, config: SimConfig) -> None:
        self.config = config
        self.loop = asyncio.new_event_loop()
        self.runner: CellRunner | None = None
        self.ready: dict[str, str | None] = {}
        self._thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self._control: ControlClient | None = None

    def start(self) -> SimulatorThread:
        self._thread.start()

        async def _start() -> dict[str, str | None]:
            self.runner = CellRunner(self.config)
            return await self.runner.start()

        self.ready = asyncio.run_coroutine_threadsafe(_start(), self.loop).result(timeout=30)
        return self

    @property
    def cell(self) -> EmulatedCell:
        assert self.runner is not None
        return self.runner.cell

    @property
    def ports(self) -> dict[str, int]:
        """The bound TCP ports by READY key (see :meth:`CellRunner.ports`)."""
        assert self.runner is not None
        return self.runner.ports()

    def control(self, cmd: str, **fields: Any) -> dict[str, Any]:
        """One control command through the real control port."""
        if self._control is None:
            endpoint = self.ready.get("control")
            if endpoint is None:
                raise RuntimeError("control port disabled")
            self._control = ControlClient(endpoint)
        return self._control(cmd, **fields)

    def stop(self) -> None:
        if self._control is not None:
            self._control.close()
            self._control = None
        if self.runner is not None and not self.runner.stopped.is_set():
            asyncio.run_coroutine_threadsafe(self.runner.stop(), self.loop).result(timeout=10)

        async def _cancel_rest() -> None:
            current = asyncio.current_task()
            rest = [t for t in asyncio.all_tasks() if t is not current]
            for task in rest:
                task.cancel()
            await asyncio.gather(*rest, return_exceptions=True)

        with contextlib.suppress(Exception):
            asyncio.run_coroutine_threadsafe(_cancel_rest(), self.loop).result(timeout=5)
        self.loop.call_soon_threadsafe(self.loop.stop)
        self._thread.join(timeout=10)
        self.loop.close()

    def __enter__(self) -> SimulatorThread:
        return self.start()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()
