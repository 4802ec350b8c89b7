"""Report sections built from tables: parameters, identifiability, plausibility, TCP.

Each function takes the loaded result (:class:`calib.result.CalibrationResult`) and returns
the inner HTML of one ``<section>``. Older or partial results (a key missing) give a
sentence saying so instead of an exception: a report of a bad run is still wanted.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from calib.html_report.fmt import (
    MISSING,
    get_list,
    get_map,
    names_list,
    num_fixed,
    num_sci,
    num_sig,
    sigma_decimals,
    table,
    text,
    yes_no,
)
from calib.result import CalibrationResult

#: DH columns: result key, parameter-name prefix, header symbol, unit, decimals.
_DH_COLUMNS = (
    ("alpha_deg", "alpha", "α", "deg", 4),
    ("a_mm", "a", "a", "mm", 3),
    ("d_mm", "d", "d", "mm", 3),
    ("theta_deg", "theta", "θ", "deg", 4),
)


def _plausibility_by_name(result: CalibrationResult) -> dict[str, Mapping[str, Any]]:
    items = get_list(result.plausibility or {}, "parameters")
    return {str(it.get("name")): it for it in items if isinstance(it, Mapping)}


def _value_cell(value: Any, sigma: Any, decimals: int, check: Mapping[str, Any] | None) -> str:
    """``value ± σ`` cell; fixed (not solved) when σ is absent; ⚠ when implausible.

    The value is rounded to the last digit of its two-significant-digit σ (GUM practice),
    and to at most ``decimals`` places.
    """
    sig = f" ± {num_sig(sigma)}" if sigma is not None else ' <span class="muted">fixed</span>'
    decimals = min(decimals, sigma_decimals(sigma)) if sigma is not None else decimals
    bad = check is not None and check.get("ok") is False
    flag = (
        f' <span class="flag" title="outside the plausible bound '
        f'±{num_fixed(check.get("bound"), 0)}" aria-label="implausible">⚠</span>'
        if bad and check is not None
        else ""
    )
    cls = "num implausible" if bad else "num"
    return f'<td class="{cls}">{num_fixed(value, decimals)}{sig}{flag}</td>'


def dh_section(result: CalibrationResult) -> str:
    """Calibrated DH table and the identified errors with ±1σ; implausible rows highlighted."""
    dh, err = result.dh or (), result.dh_error or ()
    if len(dh) != 6 or len(err) != 6:
        return "<p>No DH table in this result.</p>"
    sigma = result.uncertainty
    checks = _plausibility_by_name(result)
    head_cal = ["Joint", *(f"{sym} [{unit}]" for _, _, sym, unit, _ in _DH_COLUMNS)]
    head_err = ["Joint", *(f"Δ{sym} ± 1σ [{unit}]" for _, _, sym, unit, _ in _DH_COLUMNS)]
    rows_cal, rows_err = [], []
    for j, (cal, dif) in enumerate(zip(dh, err, strict=True), start=1):
        names = [f"{prefix}{j}" for _, prefix, _, _, _ in _DH_COLUMNS]
        bad = any(checks.get(n, {}).get("ok") is False for n in names)
        row_cls = ' class="implausible"' if bad else ""
        cells_cal = "".join(
            f'<td class="num">{num_fixed(getattr(cal, key), dec)}</td>'
            for key, _, _, _, dec in _DH_COLUMNS
        )
        rows_cal.append(f'<tr{row_cls}><th scope="row">{j}</th>{cells_cal}</tr>')
        cells_err = "".join(
            _value_cell(getattr(dif, key), sigma.get(name), dec, checks.get(name))
            for (key, _, _, _, dec), name in zip(_DH_COLUMNS, names, strict=True)
        )
        rows_err.append(f'<tr{row_cls}><th scope="row">{j}</th>{cells_err}</tr>')
    convention = "modified DH (Craig)" if result.convention == "mdh" else "classic DH"
    return (
        f"<p>Convention: {convention}. Rows with a ⚠ hold an error outside its plausible bound "
        "(see Plausibility).</p><h3>Calibrated DH table</h3>"
        + table("dh", head_cal, rows_cal, numeric={1, 2, 3, 4})
        + "<h3>Identified errors (calibrated − nominal) ± 1σ</h3><p>“fixed”: not solved for, "
        "held at the nominal value (see Identifiability).</p>"
        + table("dh dh-error", head_err, rows_err, numeric={1, 2, 3, 4})
        + _other_parameters(result, sigma, checks)
    )


def _other_parameters(
    result: CalibrationResult, sigma: Mapping[str, Any], checks: Mapping[str, Mapping[str, Any]]
) -> str:
    """Tool point, anchor(s) and indicator offset with ±1σ."""
    rows: list[tuple[str, str, Any, str]] = []  # (what, param name, value, unit)
    for axis, v in zip("xyz", result.tool_mm or (), strict=False):
        rows.append((f"Cable hook point {axis} (flange frame)", f"tool_{axis}", v, "mm"))
    anchors: list[tuple[str, Sequence[float] | None, float | None]] = [
        (result.first_anchor, result.anchor_mm, result.length_offset_mm)
    ]
    anchors += [(aid, a.anchor_mm, a.length_offset_mm) for aid, a in result.anchors.items()]
    for k, (aid, p0, offset) in enumerate(anchors):
        suffix = "" if k == 0 else f"@{aid}"
        for axis, v in zip("xyz", p0 or (), strict=False):
            rows.append((f"Anchor {aid} P0 {axis} (base frame)", f"p0_{axis}{suffix}", v, "mm"))
        rows.append((f"Anchor {aid} indicator zero offset", f"offset{suffix}", offset, "mm"))
    body = []
    for what, name, value, unit in rows:
        bad = checks.get(name, {}).get("ok") is False
        cls = ' class="implausible"' if bad else ""
        body.append(
            f'<tr{cls}><th scope="row">{text(what)}</th><td><code>{text(name)}</code></td>'
            f"{_value_cell(value, sigma.get(name), 3, checks.get(name))}"
            f"<td>{text(unit)}</td></tr>"
        )
    return "<h3>Tool point, anchor and offset</h3>" + table(
        "params", ["Parameter", "Name", "Value ± 1σ", "Unit"], body, numeric={2}
    )


def identifiability_section(result: CalibrationResult) -> str:
    """Rank, condition numbers, and every unidentifiable parameter with its reason."""
    ident = result.identifiability or {}
    if not ident:
        return "<p>No identifiability analysis in this result.</p>"
    identifiable = get_list(ident, "identifiable")
    unident = get_list(ident, "unidentifiable")
    reasons = get_map(ident, "reasons")
    summary = (
        '<dl class="summary">'
        f"<dt>Numerical rank</dt><dd>{text(ident.get('rank'))} of "
        f"{len(identifiable) + len(unident)} candidate parameters</dd>"
        "<dt>Condition number, all candidates</dt>"
        f"<dd>{num_sci(ident.get('condition_number'))}</dd>"
        "<dt>Condition number, solved set</dt>"
        f"<dd>{num_sci(ident.get('condition_number_base'))}</dd>"
        f"<dt>Rank tolerance (rtol)</dt><dd>{num_sci(ident.get('rtol'), 2)}</dd>"
        f"<dt>Solved for ({len(identifiable)})</dt><dd>{names_list(identifiable)}</dd>"
        "</dl>"
    )
    if not unident:
        return summary + "<p>Every candidate parameter is identifiable from these data.</p>"
    rows = [
        f'<tr><th scope="row"><code>{text(n)}</code></th>'
        f"<td>{text(reasons.get(n, MISSING))}</td></tr>"
        for n in unident
    ]
    return (
        summary + "<h3>Not identifiable from these data</h3><p>These parameters were held at "
        "their nominal values; the cable lengths cannot tell them apart from the solved ones.</p>"
        + table("reasons", ["Parameter", "Why"], rows)
        + _strong_correlations(result)
    )


def _strong_correlations(result: CalibrationResult, threshold: float = 0.95) -> str:
    """Pairs of solved parameters with |correlation| above ``threshold``, in words."""
    if result.correlation is None:
        return ""
    names, matrix = result.correlation.names, result.correlation.matrix
    if not names or len(matrix) != len(names):
        return ""
    pairs = []
    for i in range(len(names)):
        for j in range(i + 1, len(names)):
            try:
                r = float(matrix[i][j])
            except (TypeError, ValueError, IndexError):
                continue
            if abs(r) >= threshold:
                pairs.append((abs(r), names[i], names[j], r))
    if not pairs:
        return f"<p>No pair of solved parameters is correlated beyond |r| = {threshold}.</p>"
    pairs.sort(reverse=True)
    items = "".join(
        f"<li><code>{text(a)}</code> and <code>{text(b)}</code>: r = {num_fixed(r, 3)} "
        f"({'move together' if r > 0 else 'compensate each other'})</li>"
        for _, a, b, r in pairs[:10]
    )
    more = f"<p class='muted'>… and {len(pairs) - 10} more pairs.</p>" if len(pairs) > 10 else ""
    return (
        f"<h3>Strongly correlated solved parameters (|r| ≥ {threshold})</h3>"
        f"<p>The data determine only a combination of each pair.</p><ul>{items}</ul>{more}"
    )


def plausibility_section(result: CalibrationResult) -> str:
    """Overall verdict, cable extension, and the parameters outside their bounds."""
    pl = result.plausibility or {}
    if not pl:
        return "<p>No plausibility check in this result.</p>"
    ext = get_map(pl, "cable_extension_mm")
    params = [p for p in get_list(pl, "parameters") if isinstance(p, Mapping)]
    bad = [p for p in params if p.get("ok") is False]
    verdict = yes_no(pl.get("plausible"), "plausible", "NOT plausible")
    out = (
        f"<p>Overall: <strong>{verdict}</strong>. {len(params) - len(bad)} of {len(params)} "
        "parameters lie within their bounds (DH errors within 10 mm / 1°, tool point within "
        "500 mm of the flange, anchor within 5 m, offset within ±2000 mm).</p>"
        '<dl class="summary"><dt>Cable extension over the samples [mm]</dt>'
        f"<dd>{num_fixed(ext.get('min'), 1)} to {num_fixed(ext.get('max'), 1)} "
        f"({yes_no(ext.get('ok'), 'within the sensor range', 'outside the sensor range')})</dd>"
        "</dl>"
    )
    if not bad:
        return out
    rows = [
        f'<tr class="implausible"><th scope="row"><code>{text(p.get("name"))}</code></th>'
        f"<td>{text(p.get('kind'))}</td>"
        f'<td class="num">{num_fixed(p.get("value"), 3)}</td>'
        f'<td class="num">±{num_fixed(p.get("bound"), 0)}</td><td>{text(p.get("unit"))}</td></tr>'
        for p in bad
    ]
    return (
        out
        + f"<h3>Outside their bounds ({len(bad)})</h3>"
        + table(
            "implausible-list",
            ["Parameter", "Kind", "Value", "Bound", "Unit"],
            rows,
            numeric={2, 3},
        )
    )


def tcp_section(result: CalibrationResult) -> str:
    """The TCP position uncertainty (``tcp_uncertainty_mm``) or "not computed"."""
    tcp = result.tcp_uncertainty_mm
    if tcp is None:
        return (
            "<p>TCP position uncertainty: <strong>not computed</strong> for this result "
            "(no <code>tcp_uncertainty_mm</code> in result.json).</p>"
        )
    return (
        "<p>1σ uncertainty of the calibrated tool-point (TCP) position, as stated in "
        "<code>tcp_uncertainty_mm</code>.</p>"
    ) + table(
        "tcp",
        ["Statistic", "1σ position [mm]"],
        [
            f'<tr><th scope="row">{label}</th><td class="num">{num_fixed(tcp.get(key), 3)}</td>'
            "</tr>"
            for key, label in (("rms", "RMS over poses"), ("max", "Maximum over poses"))
        ],
        numeric={1},
    )
