"""``cablecal report RESULT.json [--data DATA.csv] [--robot MODEL] --out report.html``.

``calib`` (numpy, scipy) is imported inside the command, so ``cablecal --help`` stays light.
"""

import json
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console

from daemon.cli.errors import fail as _fail

console = Console()


def report_cmd(
    result_path: Annotated[
        Path, typer.Argument(metavar="RESULT.json", help="A result.json of `cablecal identify`.")
    ],
    out: Annotated[Path, typer.Option("--out", "-o", help="The HTML file to write.")],
    data: Annotated[
        Path | None,
        typer.Option(
            help="The samples CSV the result was identified from: adds the residual plots "
            "per sample (before and after)."
        ),
    ] = None,
    robot: Annotated[
        str | None,
        typer.Option(
            help="Nominal robot model (built-in name or .toml/.json file), for the before "
            "residuals; default the built-in model named in the result."
        ),
    ] = None,
) -> None:
    """Write the self-contained HTML calibration report of a result.json.

    Inline charts and no script: the page opens offline and prints on A4.
    """
    from calib.dataset import SampleError
    from calib.html_report import render_report_html, sample_residuals
    from calib.models import ModelError
    from calib.result import CalibrationResult, ResultError
    from daemon.datafiles import load_robot, read_samples

    try:
        doc = json.loads(result_path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise _fail(f"RESULT.json: cannot read {result_path}: {exc.strerror}") from exc
    except json.JSONDecodeError as exc:
        raise _fail(f"RESULT.json: {result_path} is not JSON: {exc}") from exc
    if not isinstance(doc, dict):
        raise _fail(f"RESULT.json: {result_path} holds {type(doc).__name__}, not an object")
    try:
        result = CalibrationResult.from_json(doc)
    except ResultError as exc:
        raise _fail(f"RESULT.json: {result_path}: {exc}") from exc
    residuals = None
    try:
        nominal = load_robot(robot) if robot is not None else None
        if data is not None:
            residuals = sample_residuals(result, read_samples(data), nominal)
    except ModelError as exc:
        raise _fail(f"--robot: {exc}") from exc
    except (SampleError, ValueError) as exc:
        raise _fail(f"--data: {exc}") from exc
    html = render_report_html(result, residuals, source=result_path.name)
    try:
        out.write_text(html, encoding="utf-8")
    except OSError as exc:
        raise _fail(f"--out: cannot write {out}: {exc.strerror}") from exc
    console.print(f"wrote {out} ({len(html) / 1024:.0f} kB)")


def register(app: typer.Typer) -> None:
    """Add ``report`` to ``app``."""
    app.command("report")(report_cmd)
