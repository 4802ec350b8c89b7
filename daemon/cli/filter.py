"""``cablecal filter``: correct the targets of a plant's robot programs, in place.

numpy, scipy and ``calib`` are imported inside the command, so ``cablecal --help`` does not
pay for them. The table fits 80 columns; the summary file has every row.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from calib.programs.formats import filter_files_help
from daemon.cli.errors import fail as _fail

SUMMARY_NAME = "filter-summary.json"
#: Exit codes: calib.filter.run's (0 all corrected, 3 some left, 2 bad input).
#: Targets of each group of left targets the table names (all with --verbose).
FIRST_OF_GROUP = 3
#: The fields of a summary row the console shows.
_SHOWN = (
    "file",
    "line",
    "name",
    "status",
    "reason",
    "group",
    "shift_mm",
    "shift_deg",
    "sigma_at_tool_mm",
)
FRAMES_HELP = escape("TOML of [uframe.N] / [utool.N] (xyz_mm, wpr_deg).")
ROBOT_HELP = escape(
    "Nominal model (built-in name or model file); default: the result's. For a robot without "
    "track or positioner, external_axes = 0 in its [controller] table lets targets that carry "
    "external axis values be corrected."
)


def register(app: typer.Typer) -> None:
    """Add ``filter`` to the ``cablecal`` app."""
    app.command(name="filter")(filter_cmd)


def _where(r: dict[str, Any]) -> str:
    return f"{r['file']}:{r['line']} {r['name']}"


def left_table(rows: list[dict[str, Any]], con: Console, verbose: bool) -> None:
    """The targets left unchanged, one line per reason: how many, and the first
    :data:`FIRST_OF_GROUP` of them (all with ``verbose``, then each with its full reason)."""
    groups: dict[str, list[dict[str, Any]]] = {}
    for r in rows:
        if "group" in r:
            groups.setdefault(r["group"], []).append(r)
    if not groups:
        return
    title = "Targets left unchanged, by reason"
    if not verbose:
        title += f" (the first {FIRST_OF_GROUP} of each; all with --verbose)"
    table = Table(title=title)
    table.add_column("n", justify="right")
    table.add_column("reason", overflow="fold", ratio=1)
    table.add_column("targets", overflow="fold", ratio=1)
    for group, members in sorted(groups.items(), key=lambda kv: (-len(kv[1]), kv[0])):
        shown = members if verbose else members[:FIRST_OF_GROUP]
        names = [escape(_where(r)) for r in shown]
        if len(members) > len(shown):
            names.append(f"… {len(members) - len(shown)} more")
        table.add_row(str(len(members)), escape(group), "\n".join(names))
    con.print(table)
    if verbose:
        for r in rows:
            if "group" in r:
                con.print(
                    f"{escape(_where(r))}: {r['status']}: {escape(r['reason'])}", highlight=False
                )


def corrected_line(rows: list[dict[str, Any]]) -> str:
    """The corrected targets in one sentence: how many, the largest shift and where, the
    largest σ at the tool."""
    done = [r for r in rows if r["status"] == "corrected"]
    if not done:
        return "no target corrected"
    shifts = [r for r in done if r["shift_mm"] is not None]
    text = f"{len(done)} corrected"
    if shifts:
        big = max(shifts, key=lambda r: r["shift_mm"])
        text += (
            f": shift up to {big['shift_mm']:.3f} mm ({_where(big)}), "
            f"{max(r['shift_deg'] or 0.0 for r in shifts):.4f} deg"
        )
    sig = [r["sigma_at_tool_mm"] for r in done if r["sigma_at_tool_mm"] is not None]
    if sig:
        text += f"; σ at the tool up to {max(sig):.3f} mm"
    return text


def summary_table(summary: dict[str, Any], con: Console, verbose: bool = False) -> None:
    """The left targets grouped by reason, the corrected ones in a sentence, the counts (of
    a ``filter-summary.json`` mapping, :meth:`calib.filter.run.FilterRun.summary`)."""
    rows = summary["targets"]
    left_table(rows, con, verbose)
    con.print(escape(corrected_line(rows)), highlight=False)
    counts = summary["counts"]
    unused = f", {counts['unused']} not used by any move" if counts["unused"] else ""
    con.print(
        f"{counts['targets']} targets: {counts.get('corrected', 0)} corrected, "
        f"{counts['left']} left unchanged{unused}",
        highlight=False,
    )


def _keep_shown(
    rows: Iterator[dict[str, Any]], shown: list[dict[str, Any]]
) -> Iterator[dict[str, Any]]:
    """``rows``, keeping in ``shown`` the fields of each that the console shows."""
    for r in rows:
        shown.append({k: r[k] for k in _SHOWN if k in r})
        yield r


def filter_cmd(
    result: Annotated[Path, typer.Argument(help="result.json of cablecal identify.")],
    files: Annotated[
        list[Path],
        typer.Argument(help=f"Program files ({filter_files_help()})."),
    ],
    out: Annotated[
        Path,
        typer.Option(
            "--out", help="Directory for the filtered files (new, empty, or a previous --out)."
        ),
    ],
    robot: Annotated[
        str | None,
        typer.Option(help=ROBOT_HELP),
    ] = None,
    frames: Annotated[Path | None, typer.Option("--frames", help=FRAMES_HELP)] = None,
    keep_joint_targets: Annotated[
        bool,
        typer.Option("--keep-joint-targets", help="Leave joint targets (taught points) alone."),
    ] = False,
    only: Annotated[
        str | None, typer.Option("--only", help="Correct only these targets: NAME,NAME,…")
    ] = None,
    verbose: Annotated[
        bool,
        typer.Option("--verbose", "-v", help="Name every target left unchanged, with its reason."),
    ] = False,
) -> None:
    """Correct every target of robot programs for the calibrated robot, in place.

    Exit codes:
    0 every target corrected
    3 some targets left unchanged (named in filter-summary.json)
    2 bad input (a file that cannot be read is not written)
    """
    from calib.filter.correct import calibration_from_result
    from calib.filter.run import filter_files, robot_check, summary_text
    from calib.programs.sites import FilterInputError, parse_frames_toml
    from daemon.cli.apply import nominal_model, read_result
    from daemon.cli.errors import printable
    from daemon.cli.filter_out import OutDirError, default_file_mode, write_set

    err = Console(stderr=True)
    res = read_result(result)
    nominal = nominal_model(res, robot, result)
    warning, mismatch = robot_check(res, nominal)
    if mismatch:
        raise _fail(f"{result}: {mismatch}")
    if warning:
        err.print(
            f"[bold yellow]warning:[/] {escape(printable(f'{result}: {warning}'))}",
            highlight=False,
            soft_wrap=True,
        )
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
    if SUMMARY_NAME in names:
        raise _fail(f"{SUMMARY_NAME} is the summary's name in --out; it is no program")
    out_dir = out.resolve()
    for f in files:
        if f.resolve().parent == out_dir:
            raise _fail(f"--out {out}: holds the input {f}; filter into another directory")
    data: list[tuple[str, bytes]] = []
    modes: dict[str, int] = {}
    for f in files:
        try:
            data.append((f.name, f.read_bytes()))
            modes[f.name] = f.stat().st_mode & 0o777
        except OSError as exc:
            raise _fail(f"{f}: cannot read: {exc.strerror}") from None
    wanted = [s.strip() for s in only.split(",") if s.strip()] if only is not None else None
    if wanted is not None and not wanted:
        raise _fail("--only: no target name given")
    run = filter_files(
        cal, data, frames=frame_tables, keep_joint_targets=keep_joint_targets, only=wanted
    )
    if run.unknown_only:
        raise _fail(
            f"--only: no target named {', '.join(run.unknown_only)} in the given files "
            "(names match without regard to case); nothing written"
        )
    extra = {"result": str(result), "robot": nominal.name}
    if warning:
        extra["warning"] = warning
    head = run.summary(extra, targets=False)
    outputs = {name: (body, modes[name]) for name, body in run.outputs.items()}
    errors, exit_code = list(run.errors), run.exit_code
    shown: list[dict[str, Any]] = []  # what the console needs of each row
    text = summary_text(head, _keep_shown(run.iter_rows(), shown))
    del run  # the summary's text has all of it now
    outputs[SUMMARY_NAME] = (text.encode("utf-8"), default_file_mode())
    del text
    try:
        write_set(out, outputs, SUMMARY_NAME)
    except OutDirError as exc:
        raise _fail(f"--out {exc}") from None
    except OSError as exc:
        raise _fail(f"--out {out}: cannot write: {exc.strerror or exc}") from None
    console = Console()  # created here so COLUMNS is read at run time
    summary_table({**head, "targets": shown}, console, verbose)
    for e in errors:
        err.print(
            f"[bold red]error:[/] {escape(printable(str(e)))} (not written)",
            highlight=False,
            soft_wrap=True,
        )
    console.print(
        f"wrote {len(outputs) - 1} file(s) and {SUMMARY_NAME} to {escape(str(out))}",
        highlight=False,
    )
    raise typer.Exit(exit_code)
