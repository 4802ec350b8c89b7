"""``cablecal identify`` and ``cablecal compare``.

``calib`` (numpy, scipy) is imported inside the commands, so ``cablecal --help`` and the
other commands do not pay for them.
"""

import json
import statistics
import time
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

# calib.options is standard library only: importing it costs nothing at ``--help`` time.
from calib.default_robot import DEFAULT_ROBOT_MODEL
from calib.options import (
    METHODS,
    PAPER_N_TEST,
    PAPER_N_TRAIN,
    IdentifyOptions,
    default,
    options_from_mapping,
    spec,
)
from daemon.cli.errors import EXIT_BAD_INPUT
from daemon.cli.errors import fail as _fail

if TYPE_CHECKING:
    from rich.progress import Progress

    from calib.models import RobotModel

if TYPE_CHECKING:
    from calib.identify import IdentifyResult

console = Console()
err_console = Console(stderr=True)

#: Exit codes of ``cablecal identify`` (documented in README's CLI section and ``--help``).
EXIT_NOT_CONVERGED = 1
EXIT_IMPLAUSIBLE = 3

#: ``cablecal identify --help``. typer's rich help keeps a single line break inside a paragraph
#: and re-wraps the lines too, so prose is one string per paragraph and the exit codes are
#: one short line each (each fits the 80-column help: no break mid-sentence).
IDENTIFY_HELP = (
    "Identify the calibrated DH parameters from a CSV of poses and cable lengths.\n\n"
    "Exit codes:\n"
    "0 done\n"
    f"{EXIT_NOT_CONVERGED} the solver did not converge (result.json is still written)\n"
    f"{EXIT_BAD_INPUT} bad input (nothing written)\n"
    f"{EXIT_IMPLAUSIBLE} with --strict: physically implausible result "
    "(result.json is still written)"
)


def _split_names(text: str) -> tuple[str, ...]:
    return tuple(n.strip() for n in text.split(",") if n.strip())


def _opt(name: str, suffix: str = "") -> Any:
    """The typer option of identification option ``name``: its help and choices from
    :mod:`calib.options` (defaults are the parameters' defaults, :func:`calib.options.default`)."""
    sp = spec(name)
    choices = f" ({', '.join(sp.choices)})" if sp.choices else ""
    return typer.Option(help=escape(f"{sp.help}{choices}{suffix}"))  # keep "[mm]" literal


def _progress() -> "Progress":
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    return Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        TextColumn("{task.percentage:>3.0f}%"),
        TimeElapsedColumn(),
        console=err_console,
        transient=True,
    )


def _run_identify(model: "RobotModel", samples: Any, opts: IdentifyOptions, **kw: Any) -> Any:
    from calib.identify import identify

    with _progress() as bar:
        task = bar.add_task(opts.method, total=1.0)

        def cb(fraction: float, message: str, /, **_: Any) -> None:
            bar.update(task, completed=fraction, description=message[:40])

        return identify(model, samples, opts, progress=cb, clock=time.perf_counter, **kw)


def _summary(fit: "IdentifyResult") -> None:
    from calib.result import DH_KEYS, CalibrationResult

    result = CalibrationResult.from_json(fit.to_json())
    table = Table(title=f"{result.robot}: {result.method} ({result.message})")
    table.add_column("figure [mm]")
    for label in ("before/train", "before/test", "after/train", "after/test"):
        table.add_column(label, justify="right")
    for key in ("rmse_mm", "mae_mm", "std_mm", "max_mm"):
        cells = []
        for stage in ("before", "after"):
            for part in ("train", "test"):
                v = result.figures(stage, part)[key]
                cells.append("-" if v is None or v != v else f"{v:.4f}")
        table.add_row(key.removesuffix("_mm"), *cells)
    console.print(table)
    dh = Table(title="DH errors (calibrated − nominal), ±1σ")
    for col in ("joint", "dalpha [deg]", "da [mm]", "dd [mm]", "dtheta [deg]"):
        dh.add_column(col, justify="right")
    for row in result.dh_error or ():
        j = row.joint
        cells = []
        for key, value in zip(DH_KEYS, row.values(), strict=True):
            sig = result.uncertainty.get(f"{key.split('_')[0]}{j}")
            cells.append(f"{value:+.4f}" + (f" ±{sig:.4f}" if sig else " (fixed)"))
        dh.add_row(str(j), *cells)
    console.print(dh)
    ident = result.identifiability or {}
    first = result.anchor_fit()
    console.print(
        f"tool_mm = {[round(v, 3) for v in result.tool()]}, anchor_mm = "
        f"{[round(v, 2) for v in first.anchor_mm]}, length_offset_mm = "
        f"{first.length_offset_mm:.3f}"
    )
    tcp = result.tcp_uncertainty_mm
    if tcp:
        console.print(
            f"predicted TCP position 1σ after best rigid alignment: RMS {tcp['rms']:.4f} mm, "
            f"max {tcp['max']:.4f} mm (workspace sample within the joint limits)"
        )
    console.print(
        f"identifiability: rank {ident['rank']}, cond {ident['condition_number']:.3g} "
        f"(base set {ident['condition_number_base']:.3g}); not identified: "
        + ", ".join(ident["unidentifiable"])
    )
    console.print(
        f"iterations {result.iterations}, {result.elapsed_s:.3f} s, prior "
        f"{'on' if result.prior and result.prior.used else 'off'}, plausible: "
        f"{result.plausible}, flagged: {len(result.flagged_samples)}"
    )
    if result.drift:
        console.print(result.drift.summary)
    flagged = result.flagged_samples
    if flagged:
        shown = ", ".join(str(i) for i in flagged[:40]) + (" …" if len(flagged) > 40 else "")
        console.print(f"flagged samples (0-based data rows, excluded from the fit): {shown}")
    for note in result.notes:
        err_console.print(f"[yellow]note:[/] {note}")


def identify_cmd(
    data: Annotated[
        Path, typer.Argument(help=escape("CSV with q1..q6 [deg], L [mm], optional anchor"))
    ],
    robot: Annotated[
        str, typer.Option(help="Built-in model name or model .toml/.json")
    ] = DEFAULT_ROBOT_MODEL,
    method: Annotated[str, _opt("method")] = default("method"),
    test_fraction: Annotated[float, _opt("test_fraction")] = default("test_fraction"),
    seed: Annotated[int, _opt("seed")] = default("seed"),
    holdout: Annotated[str, _opt("holdout")] = default("holdout"),
    robust: Annotated[str, _opt("robust")] = default("robust"),
    prior: Annotated[bool, _opt("prior")] = default("prior"),
    prior_mm: Annotated[float, _opt("prior_mm")] = default("prior_mm"),
    prior_deg: Annotated[float, _opt("prior_deg")] = default("prior_deg"),
    prior_weight: Annotated[str, _opt("prior_weight")] = default("prior_weight"),
    noise_mm: Annotated[float, _opt("noise_mm")] = default("noise_mm"),
    drift: Annotated[str, _opt("drift")] = default("drift"),
    noise_rank: Annotated[bool, _opt("noise_rank")] = default("noise_rank"),
    fix: Annotated[str, _opt("fix", ", comma-separated")] = "",
    free: Annotated[str, _opt("free", ", comma-separated")] = "",
    out: Annotated[Path | None, typer.Option(help="Write result.json here")] = None,
    strict: Annotated[
        bool, typer.Option(help="Also exit 3 when the identified parameters are implausible")
    ] = False,
) -> None:
    """Identify the calibrated DH parameters from a CSV of poses and cable lengths; the exit
    code says how it went (see :data:`IDENTIFY_HELP`, which ``--help`` shows)."""
    from calib.dataset import SampleError
    from calib.models import ModelError
    from daemon.datafiles import load_robot, read_samples

    try:
        model = load_robot(robot)
        samples = read_samples(data)
        opts = options_from_mapping(
            {
                "method": method,
                "test_fraction": test_fraction,
                "seed": seed,
                "holdout": holdout,
                "robust": robust,
                "prior": prior,
                "prior_mm": prior_mm,
                "prior_deg": prior_deg,
                "prior_weight": prior_weight,
                "noise_mm": noise_mm,
                "noise_rank": noise_rank,
                "drift": drift,
                "fix": _split_names(fix),
                "free": _split_names(free),
            }
        )
        result = _run_identify(model, samples, opts)
    except (SampleError, ModelError, ValueError) as exc:
        raise _fail(f"{data if isinstance(exc, SampleError) else 'input'}: {exc}") from None
    _summary(result)
    if out is not None:
        out.write_text(json.dumps(result.to_json(), indent=2) + "\n", encoding="utf-8")
        console.print(f"wrote {out}")
    code = exit_code(result, strict)
    if code:
        raise typer.Exit(code)


def exit_code(result: "IdentifyResult", strict: bool) -> int:
    """0, :data:`EXIT_NOT_CONVERGED` when the solver did not converge, or (``strict``)
    :data:`EXIT_IMPLAUSIBLE` when the result is physically implausible; non-convergence wins."""
    if not result.solver.success:
        err_console.print(f"[bold red]not converged:[/] {escape(result.solver.message)}")
        return EXIT_NOT_CONVERGED
    if strict and not result.plausibility["plausible"]:
        err_console.print("[bold red]implausible result[/] (--strict); see the notes above")
        return EXIT_IMPLAUSIBLE
    return 0


def compare_cmd(
    data: Annotated[
        Path | None, typer.Argument(help="CSV (default: the bundled HSR-RobotCali data)")
    ] = None,
    robot: Annotated[
        str, typer.Option(help="Built-in model name or model file")
    ] = DEFAULT_ROBOT_MODEL,
    train: Annotated[int, typer.Option(help="Training samples per run")] = PAPER_N_TRAIN,
    test: Annotated[int, typer.Option(help="Test samples per run")] = PAPER_N_TEST,
    seed: Annotated[int, typer.Option(help="First seed")] = 0,
    seeds: Annotated[int, typer.Option(help="Number of seeds (runs) to average")] = 1,
    methods: Annotated[str, typer.Option(help="Comma-separated methods")] = ",".join(METHODS),
    prior: Annotated[bool, typer.Option(help="MAP prior toward nominal")] = False,
    out: Annotated[Path | None, typer.Option(help="Write the table as JSON here")] = None,
) -> None:
    """Compare all methods on the paper's protocol (Table VIII/IX style)."""
    from calib.dataset import SampleError
    from calib.models import ModelError
    from calib.protocol import check_protocol
    from daemon.datafiles import load_robot, read_samples

    try:
        model = load_robot(robot)
        samples = read_samples(data)
        chosen = _split_names(methods)
        check_protocol(samples, chosen, train, test)
    except (SampleError, ModelError, ValueError) as exc:
        raise _fail(str(exc)) from None
    rows = compare(model, samples, chosen, train, test, seed, seeds, prior)
    table = Table(
        title=f"{len(samples)} samples, {train} train / {test} test, "
        f"{seeds} seed(s) from {seed}, mean over seeds"
    )
    for col in (
        "method",
        "before RMSE",
        "RMSE",
        "MAE",
        "MAX",
        "iterations",
        "time [s]",
        "plausible",
    ):
        table.add_column(col, justify="right")
    for r in rows:
        table.add_row(
            r["method"],
            f"{r['before_rmse_mm']:.3f}",
            f"{r['rmse_mm']:.3f}",
            f"{r['mae_mm']:.3f}",
            f"{r['max_mm']:.3f}",
            f"{r['iterations']:.1f}",
            f"{r['time_s']:.3f}",
            f"{r['plausible']}/{seeds}",
        )
    console.print(table)
    if out is not None:
        out.write_text(json.dumps(rows, indent=2) + "\n", encoding="utf-8")


def register(app: typer.Typer) -> None:
    """Add ``identify`` and ``compare`` to ``app``."""
    app.command("identify", help=IDENTIFY_HELP)(identify_cmd)
    app.command("compare")(compare_cmd)


def compare(
    model: "RobotModel",
    samples: Any,
    methods: tuple[str, ...],
    n_train: int,
    n_test: int,
    seed: int,
    seeds: int,
    prior: bool = False,
) -> list[dict[str, Any]]:
    """Mean test figures per method over ``seeds`` draws of the paper's protocol
    (:mod:`calib.protocol`), from seed ``seed`` on."""
    from calib.protocol import run_protocol

    acc: dict[str, list[dict[str, float]]] = {m: [] for m in methods}
    with _progress() as bar:
        task = bar.add_task("compare", total=len(methods) * seeds)
        runs = run_protocol(
            model,
            samples,
            methods,
            range(seed, seed + seeds),
            n_train,
            n_test,
            prior,
            clock=time.perf_counter,
        )
        for run in runs:
            res = run.result
            fig = res.metrics["after"]["test"]
            acc[run.method].append(
                {
                    "rmse_mm": fig["rmse_mm"],
                    "mae_mm": fig["mae_mm"],
                    "max_mm": fig["max_mm"],
                    "before_rmse_mm": res.metrics["before"]["test"]["rmse_mm"],
                    "iterations": float(res.solver.iterations),
                    "time_s": res.elapsed_s,
                    "plausible": float(res.plausibility["plausible"]),
                }
            )
            bar.update(task, description=f"seed {run.seed} {run.method}")
            bar.advance(task)
    rows = []
    for m in methods:
        runs_m = acc[m]
        row: dict[str, Any] = {"method": m}
        for key in runs_m[0]:
            row[key] = statistics.fmean(r[key] for r in runs_m)
        row["plausible"] = int(sum(r["plausible"] for r in runs_m))
        rows.append(row)
    return rows
