"""``cablecal plan``: plan the poses of a calibration campaign (:mod:`calib.planning`).

numpy and ``calib`` are imported inside the command, so ``cablecal --help`` does not pay for
them. Engine options left unset take :class:`calib.planning.PlanOptions`' defaults (the help
texts quote them; tests/test_plan_cli.py keeps the two in step).
"""

import json
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console, RenderableType
from rich.markup import escape
from rich.table import Table
from rich.text import Text

from calib.default_robot import DEFAULT_ROBOT_MODEL
from calib.planning.options import PlanOptions as _PlanOptions
from daemon.cli.errors import fail as _fail

#: The defaults the help names: read from calib's one definition (standard library only).
_D = _PlanOptions()


def _csv(values: tuple[float, ...]) -> str:
    return ",".join(f"{v:g}" for v in values)


def parse_floats(text: str, option: str, count: int, what: str) -> tuple[float, ...]:
    """``count`` comma-separated finite numbers; ``ValueError`` naming ``option`` otherwise,
    e.g. ``"--anchor-mm: expected X,Y,Z in mm, got '1,2'"``."""
    parts = [p.strip() for p in text.split(",")]
    try:
        values = tuple(float(p) for p in parts)
    except ValueError:
        values = ()
    if len(values) != count or any(v != v or v in (float("inf"), float("-inf")) for v in values):
        raise ValueError(f"{option}: expected {what}, got {text!r}")
    return values


#: The engine's names (``calib.planning``'s ``ValueError`` messages start with them) → options.
_OPTION_OF = {"anchors_mm": "--anchor-mm", "anchor_ids": "--anchor-id", "anchor": "--anchor-mm"}


def option_error(message: str) -> str:
    """An engine error message with its leading field name as the command-line option:
    ``"n: must be at least 1"`` → ``"--n: must be at least 1"``."""
    head, sep, rest = message.partition(":")
    word = head.split(" ", 1)[0]
    if word in _OPTION_OF:
        return (
            f"{_OPTION_OF[word]}: {message}" if word == "anchor" else _OPTION_OF[word] + sep + rest
        )
    if sep and head.isidentifier():
        return "--" + head.replace("_", "-") + sep + rest
    return message


#: Width the summary is laid out for [characters].
WIDTH = 80


def _fmt(v: float | None) -> str:
    """A σ: 4 decimals, or 3 significant digits when huge (degenerate data)."""
    return "-" if v is None else f"{v:.4f}" if abs(v) < 1e3 else f"{v:.3g}"


def summary_renderables(data: dict[str, Any], has_start: bool = False) -> list[RenderableType]:
    """The printed summary of a plan (``PlanResult.to_json()``); every table fits 80 columns.
    ``has_start``: the plan was made with start data (its condition number is shown)."""
    out: list[RenderableType] = []
    anchors = ", ".join(
        f"{a} ({', '.join(f'{v:.0f}' for v in xyz)}) x{data['poses_per_anchor'][a]}"
        for a, xyz in data["anchors"].items()
    )
    head = f"{data['n_poses']} poses at {anchors} [mm]; {data['n_candidates']} candidates, "
    out.append(Text(head + f"{data['exchanges']} exchanges, {data['elapsed_s']:.1f} s"))
    tcp = data["tcp_sigma_mm"]
    quality = Table(title=f"Predicted quality (noise {data['noise_mm']} mm per length)")
    quality.add_column("figure")
    quality.add_column("plan", justify="right")
    quality.add_column("random, same n", justify="right")
    quality.add_row(escape("TCP 1σ RMS [mm]"), _fmt(tcp["plan"]["rms"]), _fmt(tcp["random"]["rms"]))
    quality.add_row(escape("TCP 1σ max [mm]"), _fmt(tcp["plan"]["max"]), _fmt(tcp["random"]["max"]))
    start = data["condition_number_start"]
    cond = f"{data['condition_number']:.3g}" if data["condition_number"] else "inf"  # None: inf
    quality.add_row("condition number", cond, "-")
    if has_start:
        quality.add_row("cond., start data", f"{start:.3g}" if start else "inf", "-")
    out.append(quality)
    # σ 0 is the engine's mark of a direction with no information (an anchor without poses).
    cells = [
        (p["name"], f"{_fmt(p['sigma'])} {p['unit']}" if p["sigma"] > 0 else "no data")
        for p in data["parameters"]
    ]
    # As many name/σ pairs per row as 80 columns hold (each cell has 1 space of padding on
    # each side and a border).
    pair_w = max(len(c[0]) for c in cells) + max(len(c[1]) for c in cells) + 6
    per_row = max(1, min(3, (WIDTH - 1) // pair_w))
    params = Table(title="Predicted 1σ of the base parameters", show_header=False)
    for _ in range(per_row):
        params.add_column(style="bold", no_wrap=True)
        params.add_column(justify="right", no_wrap=True)
    for i in range(0, len(cells), per_row):
        chunk = cells[i : i + per_row] + [("", "")] * (per_row - len(cells[i : i + per_row]))
        params.add_row(*[c for pair in chunk for c in pair])
    out.append(params)
    times = f"moves {data['travel_s'] / 60:.1f} min, campaign (moves + dwell) "
    out.append(Text(times + f"{data['campaign_s'] / 60:.1f} min"))
    gain = data.get("anchor_gain")
    if gain:
        table = Table(title="Several anchors against one")
        for col in ("anchors", "log det / kin. param", escape("TCP 1σ RMS [mm]")):
            table.add_column(col, justify="right")
        for aid, row in gain["single_anchor"].items():
            table.add_row(
                f"{aid} only", f"{row['kinematic_log_det']:.3f}", _fmt(row["tcp_sigma_mm"]["rms"])
            )
        table.add_row(
            "all",
            f"{gain['all_anchors']['kinematic_log_det']:.3f}",
            _fmt(gain["all_anchors"]["tcp_sigma_mm"]["rms"]),
        )
        out.append(table)
        gains = (
            f"gain over {gain['best_single_anchor']} alone: D-efficiency "
            f"x{gain['d_efficiency_gain']:.2f}, TCP RMS x{gain['tcp_rms_ratio']:.2f}; "
            f"the plan uses {gain['plan_uses']}"
        )
        out.append(Text(gains))
    out.extend(Text(f"note: {n}") for n in data["notes"])
    return out


PLAN_HELP = (
    "Plan the poses of a campaign (D-optimal on the identifiable parameters, then refined "
    "for the predicted TCP accuracy) and print the predicted accuracy against as many "
    "random poses."
)


def plan_cmd(
    out: Annotated[Path, typer.Option(help="Write the plan CSV here (q1..q6 [deg], …)")],
    robot: Annotated[
        str, typer.Option(help="Built-in model name or model .toml/.json")
    ] = DEFAULT_ROBOT_MODEL,
    anchor_mm: Annotated[
        list[str] | None,
        typer.Option(
            help="Sensor anchor guess X,Y,Z [mm] in the robot base frame; repeat "
            "for several anchors (default with --start: the start data's)"
        ),
    ] = None,
    anchor_id: Annotated[
        list[str] | None, typer.Option(help="Id per --anchor-mm (default A, B, …)")
    ] = None,
    n: Annotated[int | None, typer.Option(help=f"Poses to plan, all anchors ({_D.n})")] = None,
    min_z_mm: Annotated[
        float | None,
        typer.Option(help=f"Flange and tool point above this z [mm] ({_D.min_z_mm:g})"),
    ] = None,
    candidates: Annotated[
        int | None, typer.Option(help=f"Random feasible candidate poses ({_D.candidates})")
    ] = None,
    seed: Annotated[int | None, typer.Option(help=f"Random seed ({_D.seed})")] = None,
    start: Annotated[
        Path | None, typer.Option(help="CSV of poses already measured (identify's format)")
    ] = None,
    extension_mm: Annotated[
        str | None,
        typer.Option(help=f"Allowed cable extension MIN,MAX [mm] ({_csv(_D.extension_mm)})"),
    ] = None,
    anchor_uncertainty_mm: Annotated[
        float | None,
        typer.Option(
            help=f"How far the anchor guess may be off [mm] ({_D.anchor_uncertainty_mm:g})"
        ),
    ] = None,
    noise_mm: Annotated[
        float | None,
        typer.Option(help=f"1σ length noise for the predictions [mm] ({_D.noise_mm:g})"),
    ] = None,
    joint_speed_deg_s: Annotated[
        str | None,
        typer.Option(help=f"Six joint speeds [deg/s] ({_csv(_D.joint_speed_deg_s)})"),
    ] = None,
    dwell_s: Annotated[
        float | None, typer.Option(help=f"Settle and read time per pose [s] ({_D.dwell_s:g})")
    ] = None,
    criterion: Annotated[
        str | None,
        typer.Option(help="tcp: D-optimal then TCP-variance exchanges (default); d: D only"),
    ] = None,
    json_out: Annotated[
        Path | None, typer.Option("--json", help="Write the summary as JSON here")
    ] = None,
) -> None:
    """Plan the poses of a campaign (D-optimal on the identifiable parameters) and print
    the predicted accuracy against as many random poses.

    Over 80 lines only because its options are declared in its signature (typer's way); the
    body is short. ``--help`` shows :data:`PLAN_HELP`, not this docstring.
    """
    from calib.dataset import SampleError
    from calib.models import ModelError
    from calib.planning import PlanOptions, plan, start_anchors_mm
    from calib.planning.start import plan_anchor_ids, start_offsets_mm
    from daemon.datafiles import load_robot, read_samples

    console = Console()  # created here so COLUMNS is read at run time
    try:
        model = load_robot(robot)
        kw: dict[str, Any] = {
            k: v
            for k, v in (
                ("n", n),
                ("min_z_mm", min_z_mm),
                ("candidates", candidates),
                ("seed", seed),
                ("anchor_uncertainty_mm", anchor_uncertainty_mm),
                ("noise_mm", noise_mm),
                ("dwell_s", dwell_s),
                ("criterion", criterion),
            )
            if v is not None
        }
        if extension_mm is not None:
            kw["extension_mm"] = parse_floats(extension_mm, "--extension-mm", 2, "MIN,MAX in mm")
        if joint_speed_deg_s is not None:
            kw["joint_speed_deg_s"] = parse_floats(
                joint_speed_deg_s, "--joint-speed-deg-s", 6, "six speeds in deg/s"
            )
        samples = read_samples(start) if start is not None else None
        anchors = [parse_floats(a, "--anchor-mm", 3, "X,Y,Z in mm") for a in anchor_mm or []]
        ids = list(anchor_id or [])
        if not anchors:
            if samples is None:
                raise ValueError("--anchor-mm: required (X,Y,Z in mm) without --start")
            found = start_anchors_mm(model, samples)
            anchors, ids = [tuple(p0.tolist()) for p0 in found.values()], list(found)
        if ids and len(ids) != len(anchors):
            raise ValueError(f"--anchor-id: {len(ids)} ids for {len(anchors)} anchors")
        if ids:
            kw["anchor_ids"] = tuple(ids)
        if samples is not None:  # the start samples' zero offsets keep the readings in range
            kw["offsets_mm"] = start_offsets_mm(
                model, samples, plan_anchor_ids(kw.get("anchor_ids"), len(anchors))
            )
        opts = PlanOptions(**kw)
        with console.status("planning…"):
            res = plan(model, anchors, opts, start=samples)
    except SampleError as exc:
        raise _fail(f"--start {start}: {exc}") from None
    except ModelError as exc:
        raise _fail(f"--robot: {exc}") from None
    except ValueError as exc:
        raise _fail(option_error(str(exc))) from None
    data = res.to_json()
    for item in summary_renderables(data, has_start=samples is not None):
        console.print(item)
    out.write_text(res.to_csv(), encoding="utf-8")
    console.print(f"wrote {out} ({data['n_poses']} poses)")
    if json_out is not None:
        json_out.write_text(json.dumps(data, indent=2) + "\n", encoding="utf-8")


def register(app: typer.Typer) -> None:
    """Add ``plan`` to ``app``."""
    app.command("plan", help=PLAN_HELP)(plan_cmd)
