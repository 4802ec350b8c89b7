"""``cablecal serve``: the daemon (REST API + sampler + jobs) under uvicorn, with systemd notify.

Start-up order: settings → logging → token → uvicorn (its lifespan opens the store, starts the
job pool and the sampler) → once the socket listens: ``READY=1`` and the watchdog task on the
same event loop. The line ``SERVING {json}`` on stdout gives ``url`` (and ``token`` when it was
generated) to scripts and tests.

uvicorn, FastAPI, pydantic and the daemon's modules are imported when the command runs, not
when the command line is built.
"""

import contextlib
import json
import logging
import os
import sys
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING, Any

import typer

from daemon.defaults import API_PORT

if TYPE_CHECKING:
    import uvicorn

    from daemon.config import Settings

log = logging.getLogger("cablecal.serve")


def _fail(message: str) -> typer.Exit:
    typer.echo(f"error: {message}", err=True)
    return typer.Exit(2)


def load_settings(
    config: Path | None,
    simulated_cell: Path | None,
    host: str | None,
    port: int | None,
    robot_kind: str | None = None,
) -> "Settings":
    """Settings from the file, the environment and the command-line overrides."""
    from daemon.config import ConfigError, Settings, simulated_cell_overrides

    overrides: dict[str, Any] = {}
    if host is not None:
        overrides["host"] = host
    if port is not None:
        overrides["port"] = port
    settings = Settings.load(config, **overrides)
    if robot_kind is not None and simulated_cell is None:
        raise ConfigError(
            "--robot-kind: only with --simulated-cell (for a real controller set [robot] kind)"
        )
    if simulated_cell is not None:
        try:
            ready = json.loads(simulated_cell.read_text(encoding="utf-8"))
        except (OSError, json.JSONDecodeError) as exc:
            raise ConfigError(f"--simulated-cell: cannot read {simulated_cell}: {exc}") from exc
        if not isinstance(ready, dict):
            raise ConfigError("--simulated-cell: expected the JSON object of the READY line")
        overrides.update(simulated_cell_overrides(ready, settings, robot_kind))
        settings = Settings.load(config, **overrides)
    check = getattr(settings.robot, "check", None)
    if check is not None:
        try:
            check()  # e.g. the controller password's source, before anything starts
        except ValueError as exc:
            raise ConfigError(f"robot.{exc}") from exc
    return settings


def write_token_file(state_dir: Path, token: str) -> Path:
    """Write a generated token to ``STATE_DIR/api-token`` (mode 0600)."""
    state_dir.mkdir(parents=True, exist_ok=True)
    path = state_dir / "api-token"
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write(token + "\n")
    os.chmod(path, 0o600)
    return path


def _notifying_server(config: "uvicorn.Config", notifier: Any) -> "uvicorn.Server":
    """uvicorn's server, telling systemd ``STOPPING=1`` as soon as a stop signal arrives
    (uvicorn re-raises SIGTERM after its shutdown, so code after ``serve()`` may not run)."""
    import uvicorn

    class NotifyingServer(uvicorn.Server):
        def handle_exit(self, sig: int, frame: FrameType | None) -> None:
            notifier.stopping()
            super().handle_exit(sig, frame)

    return NotifyingServer(config)


async def serve(settings: "Settings", token: str, generated: bool) -> int:
    """Run until SIGTERM/SIGINT; returns the exit code."""
    import asyncio

    import uvicorn

    from daemon.api.http.server import uvicorn_options
    from daemon.api.main import create_app
    from daemon.process.notify import Notifier, watchdog_loop

    app = create_app(settings, token)
    config = uvicorn.Config(
        app,
        host=settings.host,
        port=settings.port,
        log_config=None,
        access_log=False,
        lifespan="on",
        timeout_graceful_shutdown=5,
        **uvicorn_options(  # daemon/api/http/server.py
            settings.max_connections_per_client, send_timeout_s=settings.requests.send_timeout_s
        ),
    )
    notifier = Notifier.from_env()
    server = _notifying_server(config, notifier)
    serve_task = asyncio.create_task(server.serve(), name="uvicorn")
    while not server.started and not serve_task.done():
        await asyncio.sleep(0.02)
    if not server.started:
        await serve_task
        return 1
    port = server.servers[0].sockets[0].getsockname()[1]
    url = f"http://{settings.host}:{port}"
    line: dict[str, Any] = {"url": url, "docs": f"{url}/docs", "db": str(settings.database_path)}
    if generated:
        line["token"] = token
    print("SERVING " + json.dumps(line), flush=True)
    log.info("listening on %s", url)

    def health() -> str | None:
        state = getattr(app.state, "cablecal", None)
        if state is None or state.sampler is None:
            return "starting"
        st = state.sampler.status()
        devices = ", ".join(f"{d['name']} {d['state']}" for d in st["devices"].values())
        return f"{st['sampler']['mode']} mode; {devices}; jobs active {state.jobs.active}"

    notifier.ready(status=health())
    watchdog = asyncio.create_task(watchdog_loop(notifier, health), name="watchdog")
    try:
        await serve_task
    finally:
        notifier.stopping()
        watchdog.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await watchdog
    return 0


def register(app: typer.Typer) -> None:
    """Add ``serve`` to the CLI."""

    @app.command("serve")
    def serve_cmd(
        config: Path | None = typer.Option(
            None, "--config", "-c", help="TOML settings file (see deploy/cablecal.toml.example)."
        ),
        simulated_cell: Path | None = typer.Option(
            None,
            "--simulated-cell",
            help="JSON of the READY line of `cablecal simulate`: use its emulated devices.",
        ),
        host: str | None = typer.Option(None, help="Bind address (default 127.0.0.1)."),
        port: int | None = typer.Option(None, help=f"TCP port (default {API_PORT}, 0 = any free)."),
        robot_kind: str | None = typer.Option(
            None,
            "--robot-kind",
            help="With --simulated-cell: the emulated controller face the robot driver reads, "
            "any robot kind but manual (default huashu-socketcmd).",
        ),
    ) -> None:
        """Run the daemon: sampler, SQLite store, identification jobs and the REST API."""
        import asyncio
        import faulthandler

        from pydantic import ValidationError

        from daemon.config import ConfigError
        from daemon.process.logs import setup_logging

        # The watchdog kills a hung daemon with SIGABRT: dump every thread's stack first.
        faulthandler.enable()

        try:
            settings = load_settings(config, simulated_cell, host, port, robot_kind)
            token, generated = settings.resolve_token()
        except ValidationError as exc:
            raise _fail(f"configuration: {exc}") from exc
        except ConfigError as exc:
            raise _fail(str(exc)) from exc
        setup_logging(settings.log_level, settings.log_json)
        if generated:
            path = write_token_file(settings.state_dir, token)
            log.warning("no api_token configured: generated one for this run, in %s", path)
        code = asyncio.run(serve(settings, token, generated))
        sys.exit(code)
