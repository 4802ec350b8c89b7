"""``make run`` and ``make demo``: the daemon against an emulated cell, on this machine.

``python -m daemon.cli.demo serve``
    Starts the emulated cell (``examples/sim.toml``) and ``cablecal serve`` on it, with the
    embedded SQLite store under ``.state/``; prints the URL and the token; runs until Ctrl-C.
``python -m daemon.cli.demo campaign [--poses 100]``
    A whole campaign through the REST API, self-contained: starts a fast emulated cell and the
    daemon in a temporary directory, creates a campaign, auto-captures the poses, runs
    ``ukf-vslm``, and prints the before/after figures and the error against the cell's truth.

Everything here is the EMULATED cell: no hardware is touched.
"""

from __future__ import annotations

import secrets
import signal
import tempfile
import time
from pathlib import Path

import typer
from rich.console import Console
from rich.table import Table

from calib.accuracy import length_metrics
from calib.default_robot import DEFAULT_ROBOT_MODEL
from calib.planning.progress import match_poses
from calib.predict import predict_lengths_from_result
from calib.sample_fields import DEFAULT_ANCHOR
from daemon.cli.emulated import (
    FAST_CELL_NOISE_MM,
    FAST_DAEMON_ENV,
    Cell,
    DaemonProcess,
    EmulatedCellProcess,
    fast_cell_toml,
    wait_for,
)
from daemon.defaults import API_PORT
from daemon.store.rows import JOB_FINISHED, JobState

#: ``--help``: one paragraph, one string (typer's rich help would keep the docstring's line
#: breaks and re-wrap its lines, breaking them mid-sentence at 80 columns).
DEMO_HELP = (
    "make run and make demo: the daemon against an EMULATED cell on this machine (no hardware "
    "is touched). serve: the cell and cablecal serve until Ctrl-C; campaign: a whole campaign "
    "through the REST API in a temporary directory."
)
app = typer.Typer(add_completion=False, no_args_is_help=True, help=DEMO_HELP)
console = Console()

ROOT = Path(__file__).resolve().parents[2]


@app.command("serve")
def serve_cmd(
    sim_config: Path = typer.Option(ROOT / "examples" / "sim.toml", help="Emulated cell."),
    state_dir: Path = typer.Option(ROOT / ".state", help="SQLite store and logs."),
    port: int = typer.Option(API_PORT, help="API port (0: any free port)."),
) -> None:
    """Emulated cell + daemon in the foreground until Ctrl-C (``make run``)."""
    import os

    # SIGTERM (e.g. from a supervisor) stops both children like Ctrl-C does; they run in
    # their own sessions, so they do not get the terminal's signals themselves.
    signal.signal(signal.SIGTERM, signal.default_int_handler)
    state_dir.mkdir(parents=True, exist_ok=True)
    token = os.environ.get("CABLECAL_API_TOKEN") or secrets.token_urlsafe(18)
    sim = EmulatedCellProcess(sim_config, state_dir)
    try:
        daemon = DaemonProcess(
            sim.ready_path, state_dir, token, env={"CABLECAL_LOG_JSON": "false"}, port=port
        )
    except BaseException:
        sim.stop()
        raise
    console.print(f"[bold]cablecal[/] on the EMULATED cell ({sim_config.name})")
    console.print("  open (URL with the token, one line; the page keeps the token for the tab):")
    # Plain print: one line that a terminal does not wrap or restyle, to copy as it is.
    print(f"  {daemon.url}/#token={token}", flush=True)
    # soft_wrap: every line whole even when the output is not a terminal (rich would wrap it at
    # 80 columns, breaking the commands below mid-line); a terminal still wraps visually.
    console.print(f"  REST API docs  {daemon.url}/docs", soft_wrap=True)
    console.print(f"  token          {token}", soft_wrap=True)
    console.print(f"  database       {state_dir / 'cablecal.sqlite3'}", soft_wrap=True)
    console.print(
        f"  logs           {state_dir / 'daemon.log'}, {state_dir / 'simulator.log'}",
        soft_wrap=True,
    )
    if sim.ready.get("control"):
        console.print(
            f"  robot program  cablecal emulated-robot-run PLAN_FILE --control "
            f"{sim.ready['control']}  (a plan downloaded from the page: the EMULATED robot "
            "runs it)",
            highlight=False,
            soft_wrap=True,
        )
    console.print(
        f"  try: curl -H 'Authorization: Bearer {token}' {daemon.url}/api/v1/status\n"
        "Ctrl-C stops both.",
        soft_wrap=True,
    )
    try:
        while daemon.popen.poll() is None and sim.popen.poll() is None:
            time.sleep(0.5)
        console.print("[red]a process exited[/]; see the logs above")
    except KeyboardInterrupt:
        pass
    finally:
        daemon.stop()
        sim.stop()


@app.command("campaign")
def campaign_cmd(
    poses: int = typer.Option(100, min=40, help="Poses to auto-capture."),
    method: str = typer.Option("ukf-vslm", help="Identification method."),
    seed: int = typer.Option(1, help="Seed of the emulated cell."),
) -> None:
    """A whole campaign over REST against a fresh emulated cell (``make demo``)."""
    with tempfile.TemporaryDirectory(prefix="cablecal-demo-") as tmp:
        toml = fast_cell_toml(poses + 30, seed)
        with Cell(Path(tmp), toml, daemon_env=FAST_DAEMON_ENV) as cell:
            assert cell.daemon is not None and cell.sim is not None
            api = cell.daemon.client()
            console.print(f"daemon {cell.daemon.url} on the EMULATED cell; campaign of {poses}")
            cid = api.post("/campaigns", json={"name": "demo", "robot_model": DEFAULT_ROBOT_MODEL})
            cid.raise_for_status()
            campaign_id = int(cid.json()["id"])
            api.put(f"/campaigns/{campaign_id}/auto-capture", json={"enabled": True})
            t0 = time.monotonic()

            def count() -> int:
                n = len(api.get(f"/campaigns/{campaign_id}/samples").json())
                console.print(f"\r  {n}/{poses} captures", end="")
                return n if n >= poses else 0

            wait_for(count, timeout_s=poses * 6.0, interval_s=2.0, what=f"{poses} captures")
            api.put(f"/campaigns/{campaign_id}/auto-capture", json={"enabled": False})
            console.print(f"\n  captured in {time.monotonic() - t0:.0f} s")
            job = api.post(
                f"/campaigns/{campaign_id}/identifications",
                json={"method": method, "test_fraction": 0.2, "seed": 0},
            )
            job.raise_for_status()
            job_id = job.json()["id"]
            done = wait_for(
                lambda: (
                    (j := api.get(f"/identifications/{job_id}").json())["status"] in JOB_FINISHED
                    and j
                ),
                timeout_s=300,
                interval_s=0.5,
                what="identification",
            )
            if done["status"] != JobState.SUCCEEDED:
                console.print(f"[red]identification {done['status']}[/]: {done.get('error')}")
                raise typer.Exit(1)
            result = done["result"]
            _print_result(result)
            samples = api.get(f"/campaigns/{campaign_id}/samples").json()
            q_seen = [[float(s[f"q{j}"]) for j in range(1, 7)] for s in samples]
            all_poses = cell.sim.control("poses")["poses_deg"]
            # A pose is new when no sample lies within 0.05 deg of it on every joint.
            seen = match_poses(
                all_poses,
                [DEFAULT_ANCHOR] * len(all_poses),
                q_seen,
                [DEFAULT_ANCHOR] * len(q_seen),
                tol_deg=0.05,
            )
            new = [p for p, k in zip(all_poses, seen, strict=True) if k < 0]
            if new:
                truth = cell.sim.control("true_lengths", joints_deg=new)["lengths_mm"]
                fig = length_metrics(truth, predict_lengths_from_result(result, new))
                console.print(
                    f"against the cell's truth at {len(new)} poses never captured: "
                    f"RMSE {fig['rmse_mm']:.4f} mm, MAX {fig['max_mm']:.4f} mm "
                    f"(noise {FAST_CELL_NOISE_MM:g} mm)"
                )


def _print_result(doc: dict[str, object]) -> None:
    from calib.result import CalibrationResult

    result = CalibrationResult.from_json(doc)
    table = Table(title=f"{result.method} on {result.robot}: cable-length error [mm]")
    for col in ("model", "set", "RMSE", "MAE", "STD", "MAX"):
        table.add_column(col)
    for when in ("before", "after"):
        for part in ("train", "test"):
            m = result.figures(when, part)
            table.add_row(
                when,
                part,
                *(f"{m[k]:.4f}" for k in ("rmse_mm", "mae_mm", "std_mm", "max_mm")),
            )
    console.print(table)


def main() -> None:
    """Entry point of ``python -m daemon.cli.demo``."""
    app()


if __name__ == "__main__":
    main()
