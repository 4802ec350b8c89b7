"""``cablecal filter``: correct the targets of a plant's robot programs, in place.

numpy, scipy and ``calib`` are imported inside the command, so ``cablecal --help`` does not
pay for them. The table fits 80 columns; the summary file has every row.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from daemon.cli.errors import fail as _fail

if TYPE_CHECKING:
    from calib.filter.run import FilterRun

SUMMARY_NAME = "filter-summary.json"
#: Exit codes: calib.filter.run's (0 all corrected, 3 some left, 2 bad input).
#: Rows the table prints before it shows only the targets left unchanged.
MAX_PRINTED_ROWS = 40


def register(app: typer.Typer) -> None:
    """Add ``filter`` to the ``cablecal`` app."""
    app.command(name="filter")(filter_cmd)


def write_atomic(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary file in the same directory and a
    rename: a reader never sees half a file."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            fh.write(data)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _num(v: Any, fmt: str) -> str:
    return "-" if v is None else format(v, fmt)


def summary_table(run: FilterRun, con: Console) -> None:
    """Per target: file, line, name, status, shift, configuration kept, σ at the tool."""
    rows = run.rows()
    shown = rows
    title = "Filtered targets"
    if len(rows) > MAX_PRINTED_ROWS:
        shown = [r for r in rows if r["status"] != "corrected"][:MAX_PRINTED_ROWS]
        title = (
            f"Targets left unchanged ({len(shown)} shown of {len(rows)} targets; "
            f"all in {SUMMARY_NAME})"
        )
    table = Table(title=title)
    for col, just in (
        ("file", "left"),
        ("line", "right"),
        ("name", "left"),
        ("status", "left"),
        ("mm", "right"),
        ("deg", "right"),
        ("conf", "left"),
        ("σ mm", "right"),
    ):
        fold = col in ("file", "name")
        table.add_column(escape(col), justify=just, overflow="fold" if fold else "ellipsis")  # type: ignore[arg-type]
    for r in shown:
        conf = {True: "kept", False: "changed", None: "-"}[r["configuration_kept"]]
        table.add_row(
            escape(r["file"]),
            str(r["line"]),
            escape(r["name"]),
            r["status"],
            _num(r["shift_mm"], ".3f"),
            _num(r["shift_deg"], ".4f"),
            conf,
            _num(r["sigma_at_tool_mm"], ".3f"),
        )
    if shown:
        con.print(table)
    for r in rows:
        if r["status"] != "corrected":
            con.print(
                f"{escape(r['file'])}:{r['line']} {escape(r['name'])}: {r['status']}: "
                f"{escape(r['reason'])}",
                highlight=False,
            )
    counts = run.summary()["counts"]
    con.print(
        f"{counts['targets']} targets: {counts.get('corrected', 0)} corrected, "
        f"{counts['left']} left unchanged",
        highlight=False,
    )


def filter_cmd(
    result: Annotated[Path, typer.Argument(help="result.json of cablecal identify.")],
    files: Annotated[
        list[Path],
        typer.Argument(help="Program files (RAPID, KRL .src/.dat, URScript, Fanuc .ls)."),
    ],
    out: Annotated[Path, typer.Option("--out", help="Directory for the filtered files.")],
    robot: Annotated[
        str | None,
        typer.Option(help="Nominal model (built-in name or model file); default: the result's."),
    ] = None,
    frames: Annotated[
        Path | None,
        typer.Option("--frames", help="TOML of [uframe.N] / [utool.N] (xyz_mm, wpr_deg)."),
    ] = None,
    keep_joint_targets: Annotated[
        bool,
        typer.Option("--keep-joint-targets", help="Leave joint targets (taught points) alone."),
    ] = False,
    only: Annotated[
        str | None, typer.Option("--only", help="Correct only these targets: NAME,NAME,…")
    ] = None,
) -> None:
    """Correct every target of robot programs for the calibrated robot, in place.

    Exit codes:
    0 every target corrected
    3 some targets left unchanged (named in filter-summary.json)
    2 bad input (a file that cannot be read is not written)
    """
    from calib.filter.correct import calibration_from_result
    from calib.filter.run import filter_files
    from calib.filter.sites import FilterInputError, parse_frames_toml
    from daemon.cli.apply import nominal_model, read_result

    res = read_result(result)
    nominal = nominal_model(res, robot, result)
    try:
        cal = calibration_from_result(res, nominal)
    except ValueError as exc:
        raise _fail(f"{result}: {exc}") from None
    frame_tables = None
    if frames is not None:
        try:
            frame_tables = parse_frames_toml(frames.read_text(encoding="utf-8"), str(frames))
        except OSError as exc:
            raise _fail(f"--frames {frames}: cannot read: {exc.strerror}") from None
        except UnicodeDecodeError:
            raise _fail(f"--frames {frames}: not UTF-8 text") from None
        except FilterInputError as exc:
            raise _fail(f"--frames {exc}") from None
    names = [f.name for f in files]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise _fail(
            f"two input files share the name {dup[0]!r}; they would overwrite each other in --out"
        )
    out_dir = out.resolve()
    for f in files:
        if f.resolve().parent == out_dir:
            raise _fail(f"--out {out}: holds the input {f}; filter into another directory")
    data: list[tuple[str, bytes]] = []
    for f in files:
        try:
            data.append((f.name, f.read_bytes()))
        except OSError as exc:
            raise _fail(f"{f}: cannot read: {exc.strerror}") from None
    wanted = [s.strip() for s in only.split(",") if s.strip()] if only is not None else None
    run = filter_files(
        cal, data, frames=frame_tables, keep_joint_targets=keep_joint_targets, only=wanted
    )
    try:
        out.mkdir(parents=True, exist_ok=True)
        for name, body in run.outputs.items():
            write_atomic(out / name, body)
        extra = {"result": str(result), "robot": nominal.name}
        text = json.dumps(run.summary(extra), indent=2) + "\n"
        write_atomic(out / SUMMARY_NAME, text.encode("utf-8"))
    except OSError as exc:
        raise _fail(f"--out {out}: cannot write: {exc.strerror}") from None
    console = Console()  # created here so COLUMNS is read at run time
    summary_table(run, console)
    for err in run.errors:
        Console(stderr=True).print(
            f"[bold red]error:[/] {escape(str(err))} (not written)", highlight=False, soft_wrap=True
        )
    console.print(
        f"wrote {len(run.outputs)} file(s) and {SUMMARY_NAME} to {escape(str(out))}",
        highlight=False,
    )
    raise typer.Exit(run.exit_code)
