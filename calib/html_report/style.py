"""The report's inline stylesheet (screen and print).

Kept in Python so that rendering is a pure function (no package-data read). System font
stacks only: nothing is fetched. Colours are the Okabe–Ito palette (distinguishable with the
common colour-vision deficiencies); every coloured mark also differs in dash pattern or
carries a text label, and text contrast is at least 4.5:1 (WCAG AA).
"""

from __future__ import annotations

CSS = """
:root {
  --ink: #1a1a1a; --muted: #555; --rule: #c8c8c8; --faint: #f3f3f3;
  --before: #D55E00; --after: #0072B2; --cost: #009E73;
  --bad-bg: #fde8d7; --bad-ink: #8a2d00; --ok-ink: #00603f;
}
* { box-sizing: border-box; }
html { font-size: 15px; }
body {
  margin: 0 auto; max-width: 60rem; padding: 1.5rem 2rem 3rem; color: var(--ink);
  background: #fff; line-height: 1.45;
  font-family: "Source Sans 3", "Segoe UI", "Helvetica Neue", Arial, "Liberation Sans",
    sans-serif;
}
header.report { border-bottom: 3px solid var(--ink); padding-bottom: .6rem;
  margin-bottom: 1.2rem; }
header.report h1 { font-size: 1.6rem; margin: 0 0 .2rem; letter-spacing: .01em; }
header.report .subtitle { color: var(--muted); margin: 0; }
h2 { font-size: 1.15rem; margin: 2rem 0 .6rem; padding-bottom: .2rem;
  border-bottom: 1px solid var(--rule); }
h3 { font-size: 1rem; margin: 1.2rem 0 .4rem; }
section { break-inside: auto; }
p, ul { margin: .4rem 0 .8rem; }
table { border-collapse: collapse; margin: .4rem 0 1rem; font-size: .93rem; }
th, td { padding: .28rem .6rem; border-bottom: 1px solid var(--rule); vertical-align: top; }
thead th { border-bottom: 2px solid var(--ink); text-align: left; font-weight: 600; }
th[scope=row] { text-align: left; font-weight: 600; }
td.num, th.num { text-align: right; font-variant-numeric: tabular-nums; white-space: nowrap; }
tbody tr:nth-child(even) { background: var(--faint); }
table.metrics tbody tr { background: none; }
table.metrics tbody tr:nth-child(2n) td { border-bottom: 1.5px solid var(--ink); }
table.metrics td[rowspan], table.metrics th[rowspan] { border-bottom: 1.5px solid var(--ink); }
sup { line-height: 0; }
tr.implausible, tr.implausible:nth-child(even) { background: var(--bad-bg); }
tr.implausible td, tr.implausible th { color: var(--bad-ink); }
.flag { font-weight: 700; color: var(--bad-ink); white-space: nowrap; }
.ok { color: var(--ok-ink); font-weight: 600; }
.bad { color: var(--bad-ink); font-weight: 600; }
.muted { color: var(--muted); }
dl.summary { display: grid; grid-template-columns: max-content 1fr; gap: .2rem 1.2rem;
  margin: .4rem 0 1rem; }
dl.summary dt { font-weight: 600; }
dl.summary dd { margin: 0; font-variant-numeric: tabular-nums; }
figure { margin: .6rem 0 1.2rem; break-inside: avoid; }
figcaption { font-size: .9rem; color: var(--muted); margin-top: .2rem; }
.figure-row { display: grid; grid-template-columns: 1fr 1fr; gap: 1.2rem; }
.figure-row figure { margin: .2rem 0; }
svg.chart + svg.chart { margin-top: .4rem; }
svg.chart { width: 100%; height: auto; display: block; font-family: inherit; }
.chart-grid { stroke: #e2e2e2; stroke-width: 1; }
.chart-axes { fill: none; stroke: var(--ink); stroke-width: 1; }
.chart-zero { stroke: var(--ink); stroke-width: 1; stroke-dasharray: 2 2; }
.chart-tick { font-size: 11px; fill: var(--ink); }
.chart-label { font-size: 12.5px; fill: var(--ink); font-weight: 600; }
.chart-legend { font-size: 12px; fill: var(--ink); }
polyline, line.series-before, line.series-after, line.series-cost { fill: none;
  stroke-width: 1.6; stroke-linejoin: round; }
.series-before { stroke: var(--before); stroke-dasharray: 5 3; }
.series-after { stroke: var(--after); }
.series-cost { stroke: var(--cost); }
circle.marker { stroke: none; stroke-dasharray: none; }
circle.series-before { fill: var(--before); }
circle.series-after { fill: var(--after); }
circle.series-cost { fill: var(--cost); }
polyline.hist { stroke-width: 1.8; stroke-dasharray: none; }
polyline.hist.series-before { fill: rgba(213, 94, 0, .16); }
polyline.hist.series-after { fill: rgba(0, 114, 178, .16); }
.note-list li { margin-bottom: .3rem; }
footer { margin-top: 2.5rem; padding-top: .5rem; border-top: 1px solid var(--rule);
  color: var(--muted); font-size: .85rem; }
@media print {
  @page { size: A4; margin: 15mm 14mm 16mm; }
  html { font-size: 10pt; }
  body { max-width: none; padding: 0; }
  h2 { break-after: avoid; }
  table, figure, dl.summary { break-inside: avoid; }
  tbody tr:nth-child(even) { background: none; }
  tr.implausible { background: var(--bad-bg) !important; print-color-adjust: exact;
    -webkit-print-color-adjust: exact; }
  svg.chart { max-height: 80mm; }
  a { color: inherit; text-decoration: none; }
}
"""
