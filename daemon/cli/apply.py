"""``cablecal compensate``, ``cablecal export`` and ``cablecal verify``: apply a result.

They work on a ``result.json`` written by ``cablecal identify`` (or fetched from the daemon),
without the daemon. ``calib`` (numpy, scipy) is imported inside the commands, so
``cablecal --help`` does not pay for them. Every table fits 80 columns.
"""

import json
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from daemon.cli.errors import fail as _fail

if TYPE_CHECKING:
    from calib.compensate import CompensateResult
    from calib.models import RobotModel
    from calib.result import CalibrationResult
    from calib.verify import VerifyResult

console = Console()
err_console = Console(stderr=True)

#: Per-pose rows ``verify`` prints before it shows only the largest residuals.
MAX_PRINTED_ROWS = 20


def read_result(path: Path) -> "CalibrationResult":
    """The result a ``result.json`` file holds (:mod:`calib.result`); errors name the file
    and the field."""
    from calib.result import CalibrationResult, ResultError

    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise _fail(f"{path}: cannot read: {exc.strerror}") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise _fail(f"{path}: not a result.json (invalid JSON: {exc})") from None
    try:
        result = CalibrationResult.from_json(data)
    except TypeError:
        result = None
    except ResultError as exc:
        raise _fail(f"{path}: not a valid result.json: {exc}") from None
    if result is None or result.dh is None:
        raise _fail(f"{path}: not a result.json (no 'dh' table); write one with cablecal identify")
    return result


def nominal_model(
    result: "CalibrationResult", robot: str | None, result_path: Path
) -> "RobotModel":
    """The nominal model: ``--robot`` (built-in name or model file), else the result's robot."""
    from calib.models import ModelError
    from daemon.datafiles import load_robot

    spec = robot or result.robot or ""
    try:
        return load_robot(spec)
    except (ModelError, KeyError, ValueError) as exc:
        where = "--robot" if robot else f"{result_path}: robot {spec!r}"
        raise _fail(f"{where}: {exc}; give the nominal model with --robot") from None


def _triple(text: str, option: str) -> tuple[float, float, float]:
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise _fail(f"{option}: expected X,Y,Z in mm, got {text!r}") from None
    if len(values) != 3:
        raise _fail(f"{option}: expected 3 comma-separated numbers X,Y,Z, got {text!r}")
    return values[0], values[1], values[2]


def _seed(text: str | None) -> list[float] | None:
    if text is None:
        return None
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        raise _fail(f"--seed-deg: expected q1,…,q6 in degrees, got {text!r}") from None
    if len(values) != 6:
        raise _fail(f"--seed-deg: expected 6 comma-separated angles, got {len(values)}")
    return values


def compensation_summary(out: "CompensateResult", con: Console) -> None:
    """The figures of a compensation, its flagged rows (first 10) and the note."""
    s = out.summary
    kind = "joint" if out.kind == "joints" else out.kind
    table = Table(title=f"Compensation ({kind} targets, {out.mode} mode)")
    table.add_column("figure")
    table.add_column("value", justify="right")
    table.add_row("targets", str(s["n"]))
    table.add_row("flagged", str(s["n_flagged"]))
    for flag, count in sorted(s["flag_counts"].items()):
        table.add_row(f"  {flag}", str(count))
    table.add_row(escape("max residual [mm]"), f"{s['max_residual_mm']:.4f}")
    table.add_row(
        escape("error without correction, RMS [mm]"), f"{s['rms_uncompensated_error_mm']:.4f}"
    )
    table.add_row(escape("largest joint correction [deg]"), f"{s['max_correction_deg']:.4f}")
    con.print(table)
    flagged = [r for r in out.csv_rows() if r["flags"]][:10]
    if flagged:
        rows = Table(title="Flagged targets (first 10)")
        for col in ("index", "residual [mm]", "iter", "flags"):
            rows.add_column(escape(col), justify="right" if col != "flags" else "left")
        for r in flagged:
            rows.add_row(
                str(r["index"]),
                f"{r['residual_mm']:.4f}",
                str(r["iterations"]),
                r["flags"].replace(";", ", "),
            )
        con.print(rows)
    con.print(f"[bold]note:[/] {out.note}", highlight=False)


def verify_tables(out: "VerifyResult", con: Console) -> None:
    """Metrics and per-pose residuals (the largest :data:`MAX_PRINTED_ROWS` when longer)."""
    m = out.metrics
    title = "Verification" + (" (anchor refit)" if out.refit_anchor else "")
    table = Table(title=title)
    for col in ("n", "RMSE [mm]", "MAE [mm]", "MAX [mm]", "at identification [mm]"):
        table.add_column(escape(col), justify="right")
    ref = "-" if out.reference_rmse_mm is None else f"{out.reference_rmse_mm:.4f}"
    table.add_row(
        str(int(m["n"])), f"{m['rmse_mm']:.4f}", f"{m['mae_mm']:.4f}", f"{m['max_mm']:.4f}", ref
    )
    con.print(table)
    n = out.residual_mm.shape[0]
    order = list(range(n))
    title = "Per-pose residuals (measured − predicted)"
    if n > MAX_PRINTED_ROWS:
        largest = sorted(range(n), key=lambda i: -abs(float(out.residual_mm[i])))
        order = sorted(largest[:MAX_PRINTED_ROWS])
        title += f", the {MAX_PRINTED_ROWS} largest of {n} (all: --out)"
    rows = Table(title=title)
    for col in ("index", "anchor", "measured [mm]", "predicted [mm]", "residual [mm]"):
        rows.add_column(escape(col), justify="right")
    for i in order:
        rows.add_row(
            str(i),
            out.anchor[i],
            f"{out.measured_mm[i]:.3f}",
            f"{out.predicted_mm[i]:.3f}",
            f"{out.residual_mm[i]:+.4f}",
        )
    con.print(rows)
    for note in out.notes:
        con.print(note, highlight=False)


def _write(path: Path, text: str, option: str = "--out") -> None:
    try:
        path.write_text(text, encoding="utf-8")
    except OSError as exc:
        raise _fail(f"{option} {path}: cannot write: {exc.strerror}") from None


def register(app: typer.Typer) -> None:
    """Add ``compensate``, ``export`` and ``verify`` to the ``cablecal`` app."""
    app.command(name="compensate")(compensate_cmd)
    app.command(name="export")(export_cmd)
    app.command(name="verify")(verify_cmd)


def compensate_cmd(
    result: Annotated[Path, typer.Argument(help="result.json of cablecal identify.")],
    targets: Annotated[
        Path,
        typer.Argument(help="CSV of targets: q1..q6 (deg), or x,y,z (mm) [+ rx,ry,rz (deg)]."),
    ],
    out: Annotated[Path, typer.Option("--out", help="Corrected program (CSV).")],
    tool_mm: Annotated[
        str | None, typer.Option("--tool-mm", help="TCP in the flange frame, X,Y,Z (mm).")
    ] = None,
    mode: Annotated[
        str, typer.Option("--mode", help="position (tool point) or pose (and orientation).")
    ] = "position",
    seed_deg: Annotated[
        str | None,
        typer.Option("--seed-deg", help="q1,…,q6 (deg) picking the IK branch of x,y,z targets."),
    ] = None,
    robot: Annotated[
        str | None,
        typer.Option(help="Nominal model (built-in name or model file); default: the result's."),
    ] = None,
) -> None:
    """Correct a program: the joints at which the calibrated robot reaches each target."""
    from calib.compensate import CompensateOptions, compensate, parse_targets_csv
    from calib.export import model_from_result

    if mode not in ("position", "pose"):
        raise _fail(f"--mode: expected position or pose, got {mode!r}")
    res = read_result(result)
    nominal = nominal_model(res, robot, result)
    tool = _triple(tool_mm, "--tool-mm") if tool_mm is not None else (0.0, 0.0, 0.0)
    try:
        text = targets.read_text(encoding="utf-8-sig")
    except OSError as exc:
        raise _fail(f"{targets}: cannot read: {exc.strerror}") from None
    try:
        parsed = parse_targets_csv(text, _seed(seed_deg))
    except ValueError as exc:
        hint = " (--seed-deg)" if "seed_deg" in str(exc) else ""
        raise _fail(f"{targets}: {exc}{hint}") from None
    try:
        calibrated = model_from_result(res, nominal)
        options = CompensateOptions(mode=mode, tool_mm=tool)  # type: ignore[arg-type]
        output = compensate(nominal, calibrated, parsed, options)
    except ValueError as exc:
        raise _fail(f"{targets}: {exc}") from None
    _write(out, output.to_csv())
    compensation_summary(output, console)
    console.print(f"wrote {out} ({len(output.flags)} rows)", highlight=False)


def export_cmd(
    result: Annotated[Path, typer.Argument(help="result.json of cablecal identify.")],
    fmt: Annotated[str, typer.Option("--format", help="toml, urdf or json.")],
    out: Annotated[Path, typer.Option("--out", help="Model file to write.")],
    robot: Annotated[
        str | None,
        typer.Option(help="Nominal model (joint limits); default: the result's robot."),
    ] = None,
) -> None:
    """Write the calibrated model as a model file (TOML/JSON, for --robot) or a URDF."""
    from calib.export import EXPORT_FORMATS, export_result

    if fmt not in EXPORT_FORMATS:
        raise _fail(f"--format: expected one of {', '.join(EXPORT_FORMATS)}, got {fmt!r}")
    res = read_result(result)
    nominal = nominal_model(res, robot, result)
    try:
        text = export_result(res, fmt, nominal)
    except ValueError as exc:
        raise _fail(f"{result}: {exc}") from None
    _write(out, text)
    console.print(f"wrote {out} ({fmt}, {len(text)} bytes)", highlight=False)


def verify_cmd(
    result: Annotated[Path, typer.Argument(help="result.json of cablecal identify.")],
    data: Annotated[Path, typer.Argument(help="Sample CSV of another campaign.")],
    refit_anchor: Annotated[
        bool,
        typer.Option("--refit-anchor", help="Fit the anchor P0 and zero offset (sensor moved)."),
    ] = False,
    max_rmse_mm: Annotated[
        float | None,
        typer.Option("--max-rmse-mm", help="Exit 1 when the RMSE [mm] is above this."),
    ] = None,
    out: Annotated[Path | None, typer.Option("--out", help="Per-pose residuals (CSV).")] = None,
) -> None:
    """Predict another campaign's cable lengths from a result: RMSE, MAE, MAX per pose."""
    from calib.dataset import SampleError
    from calib.verify import VerifyOptions, verify
    from daemon.datafiles import read_samples

    res = read_result(result)
    try:
        samples = read_samples(data)
    except SampleError as exc:
        raise _fail(f"{data}: {exc}") from None
    try:
        options = VerifyOptions(refit_anchor=refit_anchor, max_rmse_mm=max_rmse_mm)
    except ValueError as exc:
        raise _fail(f"--max-rmse-mm: {exc}") from None
    try:
        output = verify(res, samples, options)
    except (ValueError, KeyError) as exc:
        raise _fail(f"{data}: {exc}") from None
    verify_tables(output, console)
    if out is not None:
        _write(out, output.to_csv())
        console.print(f"wrote {out} ({len(samples)} rows)", highlight=False)
    if output.passed is False:
        err_console.print(
            f"[bold red]RMSE {output.metrics['rmse_mm']:.4f} mm is above "
            f"--max-rmse-mm {max_rmse_mm}[/]"
        )
        raise typer.Exit(1)
