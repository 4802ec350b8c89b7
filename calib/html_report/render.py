"""Assemble the self-contained HTML calibration report from a parsed ``result.json``.

The page is one string: inline CSS (:mod:`calib.html_report.style`), inline SVG charts
(:mod:`calib.html_report.svg`), no script and no reference to another host, so it opens
offline and prints on A4. Every string from the result is escaped.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from calib.html_report.fmt import (
    get_list,
    get_map,
    num_fixed,
    num_int,
    num_sig,
    table,
    text,
    yes_no,
)
from calib.html_report.residuals import SampleResiduals
from calib.html_report.style import CSS
from calib.html_report.svg import Series, histogram_chart, line_chart
from calib.html_report.tables import (
    dh_section,
    identifiability_section,
    plausibility_section,
    tcp_section,
)
from calib.result import CalibrationResult, ResultLike, Split

#: Section ids in page order, with their headings (the browser test checks each one).
SECTIONS: tuple[tuple[str, str], ...] = (
    ("summary", "Summary"),
    ("accuracy", "Accuracy before and after calibration"),
    ("drift", "Measurement drift and steps"),
    ("residuals", "Residuals per sample"),
    ("convergence", "Convergence"),
    ("parameters", "Calibrated parameters"),
    ("identifiability", "Identifiability"),
    ("plausibility", "Plausibility"),
    ("tcp-uncertainty", "TCP uncertainty"),
    ("notes", "Method notes"),
)

_METHODS = {
    "ukf-vslm": "UKF-VSLM (paper M9)",
    "lm": "Levenberg–Marquardt (M6)",
    "vslm": "variable step-size LM (M8)",
    "ukf": "unscented Kalman filter (M3)",
    "ekf": "extended Kalman filter (M1)",
    "de": "differential evolution (M7)",
    "geolm": "geodesic-acceleration LM (not in the paper)",
}


def _summary(result: CalibrationResult) -> str:
    split = result.split or Split(None, None, None, None, None, None, None)
    prior = result.prior.block if result.prior else {}
    n_train, n_test = split.n_train, split.n_test
    n_total = n_train + n_test if n_train is not None and n_test is not None else None
    method = result.method or ""
    method_long = _METHODS.get(method)
    flagged = list(result.flagged_samples)
    flagged_rows = ", ".join(text(r) for r in flagged[:20]) + (" …" if len(flagged) > 20 else "")
    converged = f"{yes_no(result.success)} — {text(result.message)} (status {text(result.status)})"
    split_text = (
        f"{text(split.holdout)} hold-out, test fraction {num_fixed(split.test_fraction, 2)}, "
        f"seed {text(split.seed)}"
    )
    prior_text = (
        f"yes: {num_sig(prior.get('dh_mm'))} mm / {num_sig(prior.get('dh_deg'))} deg per DH "
        f"error, noise {num_sig(prior.get('noise_mm'))} mm"
        if prior.get("used")
        else "no (maximum likelihood)"
    )
    rows = [
        ("Robot model", text(result.robot)),
        ("Method", text(method) + (f" — {method_long}" if method_long else "")),
        ("Samples", f"{num_int(n_total)} ({num_int(n_train)} training, {num_int(n_test)} test)"),
        ("Split", split_text),
        ("Converged", converged),
        ("Iterations", num_int(result.iterations)),
        ("Identification time [s]", num_fixed(result.elapsed_s, 3)),
        ("Robust loss", text(result.robust)),
        ("Prior toward nominal", prior_text),
        ("Flagged samples", f"{len(flagged)} (rows {flagged_rows})" if flagged else "0"),
    ]
    body = "".join(f"<dt>{k}</dt><dd>{v}</dd>" for k, v in rows)
    return f'<dl class="summary">{body}</dl>'


def _accuracy(result: CalibrationResult) -> str:
    metrics = result.metrics or {}
    before, after = get_map(metrics, "before"), get_map(metrics, "after")
    if not before and not after:
        return "<p>No metrics in this result.</p>"
    rows = []
    for subset, label in (("train", "Training"), ("test", "Test")):
        b, a = get_map(before, subset), get_map(after, subset)
        if (not b and not a) or (b.get("n") == 0 and a.get("n") == 0):
            continue  # no test set (test fraction 0)
        rb, ra = b.get("rmse_mm"), a.get("rmse_mm")
        gain = (
            num_fixed(100.0 * (1.0 - ra / rb), 1)
            if isinstance(rb, int | float) and isinstance(ra, int | float) and rb > 0
            else "—"
        )
        for k, (model, m) in enumerate((("before", b), ("after", a))):
            first = f'<th scope="row" rowspan="2">{label}</th>' if k == 0 else ""
            n_cell = f'<td class="num" rowspan="2">{num_int(m.get("n"))}</td>' if k == 0 else ""
            cells = "".join(
                f'<td class="num">{num_fixed(m.get(key), 3)}</td>'
                for key in ("rmse_mm", "mae_mm", "std_mm", "max_mm")
            )
            gain_cell = f'<td class="num" rowspan="2">{gain}</td>' if k == 0 else ""
            rows.append(f"<tr>{first}{n_cell}<td>{model}</td>{cells}{gain_cell}</tr>")
    headers = [
        "Set",
        "n",
        "Model",
        "RMSE [mm]",
        "MAE [mm]",
        "STD [mm]",
        "MAX [mm]",
        "RMSE reduction [%]",
    ]
    return (
        "<p>Cable-length residuals, measured minus model. <em>Before</em>: the nominal model "
        "with only the anchor P0 and the indicator offset fitted; <em>after</em>: the "
        "calibrated model. MAE is what the paper calls “STD”; STD is the standard deviation "
        "of the residuals.</p>" + table("metrics", headers, rows, numeric={1, 3, 4, 5, 6, 7})
    )


def _drift(result: CalibrationResult) -> str:
    """What :mod:`calib.drift` found: steps (row, kind, size) and the smooth offset drift."""
    if result.drift is None:
        return (
            "<p>Not modelled: identified with <code>drift none</code>, or a result from "
            "before drift modelling.</p>"
        )
    block = result.drift.block
    when = (
        "the samples' <code>t_s</code> [s]."
        if block.get("time_unit") == "s"
        else "the row order (no time column)."
    )
    intro = (
        f"<p>Drift mode <code>{text(block.get('mode'))}</code>; model chosen: "
        f"<strong>{text(block.get('model'))}</strong>. Changes of the measurement over the "
        "campaign are modelled as nuisance terms and left out of the robot's parameters, "
        f"compensation and TCP figures. Time: {when}</p>"
    )
    # The one wording of what was found (calib.drift.summary, carried in the result; the
    # operator page shows the same line).
    found = text(result.drift.summary)
    if block.get("note"):  # not modelled by this method: nothing was looked for
        return f"<p>{found}.</p>"
    steps = [s for s in get_list(block, "steps") if isinstance(s, Mapping)]
    rows = []
    for st in steps:
        kind = "sensor moved" if st.get("kind") == "sensor_moved" else "indicator re-zeroed"
        shift = st.get("p0_shift_mm")
        shift_txt = ", ".join(num_fixed(v, 3) for v in shift) if isinstance(shift, list) else "—"
        rows.append(
            f'<tr><td class="num">{num_int(st.get("row"))}</td><td>{kind}</td>'
            f'<td class="num">{num_fixed(st.get("offset_mm"), 3)}</td><td>{shift_txt}</td>'
            f'<td class="num">{num_fixed(st.get("size_mm"), 3)}</td></tr>'
        )
    body = intro
    if rows:
        body += table(
            "drift-steps",
            ["Row (0-based)", "Kind", "Offset step [mm]", "P0 shift x, y, z [mm]", "Size [mm]"],
            rows,
            numeric={0, 2, 4},
        )
    smooth = get_map(block, "smooth")
    if smooth:
        per = "mm/h" if block.get("time_unit") == "s" else "mm per 100 samples"
        rate = next((v for k, v in smooth.items() if k.startswith("max_rate_")), None)
        mean = next((v for k, v in smooth.items() if k.startswith("mean_rate_")), None)
        body += (
            f"<p>Smooth offset drift, piecewise linear over {len(get_list(smooth, 'knots_t'))} "
            f"knots: {num_fixed(smooth.get('peak_to_peak_mm'), 3)} mm peak to peak, steepest "
            f"{num_fixed(rate, 3)} {per}, mean {num_fixed(mean, 3)} {per}.</p>"
        )
    if not rows and not smooth:
        body += f"<p>{found}.</p>"
    return body


def _residuals(res: SampleResiduals | None) -> str:
    if res is None:
        return (
            "<p>Not shown: the report was made without the samples. Pass the data file "
            "(<code>cablecal report RESULT.json --data DATA.csv</code>) to plot the residual "
            "of every sample.</p>"
        )
    n = res.after_mm.shape[0]
    idx = np.arange(n, dtype=float)
    label = "residual [mm]"
    panels = [
        ("before", "before calibration", res.before_mm),
        ("after", "after calibration", res.after_mm),
    ]
    lines, hists = [], []
    for key, words, values in panels:
        if values is None:
            continue
        css = f"series-{key}"
        lines.append(
            line_chart(
                f"chart-residuals-{key}",
                f"Cable-length residual per sample, {words}",
                [Series(key, idx, values, css, markers=True, line=False)],
                "sample index (0-based data row)",
                label,
                zero_line=True,
                size_px=(720, 230),
            )
        )
        hist = histogram_chart(
            f"chart-histogram-{key}",
            f"Residual histogram, {words}",
            [(key, values, css)],
            label,
            bins=25,
            size_px=(360, 260),
        )
        hists.append(
            f"<figure>{hist}<figcaption>Distribution {words} (RMS "
            f"{num_fixed(_rms(values), 3)} mm).</figcaption></figure>"
        )
    before_txt = "top: before, bottom: after calibration" if len(lines) == 2 else "after only"
    return (
        f"<p>All {n} samples of the data file (training and test); residual = measured − "
        f"model cable length, L_meas − L_model. {text(res.before_note)}.</p>"
        f"<figure>{''.join(lines)}<figcaption>Figure 1. Residual of every sample, one dot per "
        f"sample ({before_txt}; each panel has its own scale).</figcaption></figure>"
        f'<div class="figure-row">{"".join(hists)}</div>'
        '<p class="muted">Figure 2. Histograms of the residuals (each on its own bins).</p>'
    )


def _rms(values: Any) -> float:
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    return float(np.sqrt(np.mean(v * v))) if v.size else float("nan")


def _convergence(result: CalibrationResult) -> str:
    history = np.array(result.cost_history_rms_mm or (), dtype=float)
    finite = history[np.isfinite(history) & (history > 0)]
    if finite.size < 2:
        return "<p>No cost history in this result (the method records none).</p>"
    log_y = bool(finite.max() / finite.min() > 20.0)
    # One series per fit (robust rounds restart, so the cost may rise between them); the x
    # axis counts whole iterations over the fits, each fit's start sharing its predecessor's
    # last iteration number.
    starts = sorted(
        {int(i) for i in result.cost_history_fit_starts or () if 0 <= i < history.size} | {0}
    )
    bounds = [*starts, history.size]
    series, x0 = [], 0
    for k in range(len(starts)):
        part = history[bounds[k] : bounds[k + 1]]
        label = "RMS residual" if k == 0 else f"fit {k + 1} (after robust reweighting)"
        series.append(
            Series(
                label,
                x0 + np.arange(part.size, dtype=float),
                part,
                "series-cost",
                markers=history.size <= 60,
            )
        )
        x0 += max(part.size - 1, 0)
    chart = line_chart(
        "chart-convergence",
        "RMS training residual at each iteration",
        series,
        "iteration",
        "RMS residual [mm]" + (" (log scale)" if log_y else ""),
        log_y=log_y,
    )
    fits = len(starts)
    how = ""
    if fits > 1:
        how = (
            f" in {fits} fits: the robust step reweighted the rows and refit, and each "
            "fit's curve starts again from its own start, so it may rise there"
        )
    return (
        f"<p>RMS residual of the training set from the start ({num_fixed(history[0], 3)} mm) "
        f"to the end ({num_fixed(history[-1], 3)} mm) over {x0} iterations{how}.</p>"
        f"<figure>{chart}<figcaption>Figure 3. Convergence of the identification "
        "(<code>cost_history_rms_mm</code>).</figcaption></figure>"
    )


def _notes(result: CalibrationResult) -> str:
    items = "".join(f"<li>{text(n)}</li>" for n in result.notes)
    body = f'<ul class="note-list">{items}</ul>' if items else "<p>The method left no notes.</p>"
    return body + f"<p>Solver message: {text(result.message)}.</p>"


def render_report_html(
    result: ResultLike,
    residuals: SampleResiduals | None = None,
    *,
    source: str | None = None,
) -> str:
    """The calibration report as one self-contained HTML document.

    Parameters
    ----------
    result : CalibrationResult or mapping
        The result (a parsed ``result.json`` is loaded: README, "result.json contract").
        Missing keys give a sentence in their section instead of an error.
    residuals : SampleResiduals, optional
        Per-sample residuals (:func:`calib.html_report.sample_residuals`); without them the
        residual section says how to get them.
    source : str, optional
        Where the result came from (file name, identification id), shown under the title.

    Returns
    -------
    str
        ``<!DOCTYPE html>`` document, UTF-8, no script, no external reference.

    Raises
    ------
    TypeError
        ``result`` is not a mapping.
    calib.result.ResultError
        A field of the wrong type (named).
    """
    result = CalibrationResult.of(result)
    bodies = {
        "summary": _summary(result),
        "accuracy": _accuracy(result),
        "drift": _drift(result),
        "residuals": _residuals(residuals),
        "convergence": _convergence(result),
        "parameters": dh_section(result),
        "identifiability": identifiability_section(result),
        "plausibility": plausibility_section(result),
        "tcp-uncertainty": tcp_section(result),
        "notes": _notes(result),
    }
    sections = "".join(
        f'<section id="{sid}" aria-labelledby="{sid}-h"><h2 id="{sid}-h">{k}. {title}</h2>'
        f"{bodies[sid]}</section>"
        for k, (sid, title) in enumerate(SECTIONS, start=1)
    )
    robot, method = text(result.robot), text(result.method)
    subtitle = f"Robot {robot} · method {method}" + (f" · {text(source)}" if source else "")
    return (
        '<!DOCTYPE html><html lang="en"><head><meta charset="utf-8">'
        '<meta name="viewport" content="width=device-width, initial-scale=1">'
        f"<title>Calibration report — {robot} — {method}</title>"
        f"<style>{CSS}</style></head><body>"
        '<header class="report"><h1>Kinematic calibration report</h1>'
        f'<p class="subtitle">{subtitle}</p></header>'
        f"<main>{sections}</main>"
        "<footer>Generated by cablecal from result.json. Lengths in mm, angles in degrees; "
        "uncertainties are 1σ. Residuals are measured minus model cable length.</footer>"
        "</body></html>"
    )
