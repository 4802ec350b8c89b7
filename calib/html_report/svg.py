"""Static SVG charts for the HTML report: line chart and histogram, rendered to a string.

No JavaScript, no external fonts or stylesheets: the SVG inherits the page's font through
CSS classes (``chart-*``) defined in :mod:`calib.html_report.style`, so it prints with the
page. Every chart carries a ``<title>`` and ``<desc>`` for screen readers, axis labels with
units, and draws series with a distinct colour *and* dash pattern (readable in greyscale and
with colour-vision deficiencies; colours from the Okabe–Ito palette).

Coordinates: a chart is ``WIDTH_PX × HEIGHT_PX`` user units with a ``viewBox``, so it scales
to the column width on screen and on paper.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from html import escape

import numpy as np

from calib.kinematics import FloatArray

WIDTH_PX = 720
HEIGHT_PX = 300
_MARGIN_LEFT = 72
_MARGIN_RIGHT = 16
_MARGIN_TOP = 28
_MARGIN_BOTTOM = 48


@dataclass(frozen=True)
class Series:
    """One data series of a chart.

    Attributes
    ----------
    label : str
        Legend text (escaped on output).
    x, y : ndarray, shape (n,)
        Data in the axis units of the chart; non-finite points are dropped.
    css_class : str
        ``series-before``, ``series-after`` or ``series-cost``: colour and dash pattern.
    markers : bool
        Draw a small marker at every point.
    line : bool
        Join the points with a line (False: a scatter plot of the markers).
    """

    label: str
    x: FloatArray
    y: FloatArray
    css_class: str
    markers: bool = False
    line: bool = True


def nice_ticks(lo: float, hi: float, target: int = 6) -> list[float]:
    """Round tick values (1, 2, 2.5 or 5 × 10^k steps) covering ``[lo, hi]``.

    Returns at least two ticks; a degenerate range is widened by ±1 (or ±10 % of ``|lo|``).
    """
    if not (math.isfinite(lo) and math.isfinite(hi)):
        raise ValueError(f"nice_ticks: range must be finite, got [{lo}, {hi}]")
    if hi < lo:
        lo, hi = hi, lo
    if hi - lo < 1e-12 * max(1.0, abs(lo)):
        pad = 0.1 * abs(lo) if lo else 1.0
        lo, hi = lo - pad, hi + pad
    raw = (hi - lo) / max(target - 1, 1)
    mag = 10.0 ** math.floor(math.log10(raw))
    step = next(m * mag for m in (1.0, 2.0, 2.5, 5.0, 10.0) if m * mag >= raw * 0.999)
    first = math.floor(lo / step + 1e-9) * step
    last = math.ceil(hi / step - 1e-9) * step
    count = round((last - first) / step)
    return [first + k * step for k in range(count + 1)]


def format_tick(value: float, step: float) -> str:
    """A tick label with as many decimals as the tick step needs (no ``0.30000000004``)."""
    if value == 0:
        return "0"
    if abs(value) >= 1e5 or abs(value) < 1e-4:
        return f"{value:.2g}".replace("e+0", "e").replace("e-0", "e-")
    decimals = max(0, -math.floor(math.log10(step) + 1e-9)) if step > 0 else 0
    if step > 0 and not math.isclose(step * 10**decimals % 1, 0, abs_tol=1e-6):
        decimals += 1  # 2.5 steps
    text = f"{value:.{decimals}f}"
    return "−" + text[1:] if text.startswith("-") else text


def _log_ticks(lo: float, hi: float) -> list[float]:
    """Ticks 1 × 10^k (plus 2 and 5 × 10^k when the range spans fewer than three decades),
    from the last one at or below ``lo`` to the first one at or above ``hi``."""
    k0, k1 = math.floor(math.log10(lo)), math.ceil(math.log10(hi))
    mantissas = (1.0, 2.0, 5.0) if k1 - k0 < 3 else (1.0,)
    ticks = [m * 10.0**k for k in range(k0, k1 + 1) for m in mantissas]
    first = max(t for t in ticks if t <= lo * 1.0001)
    last = min(t for t in ticks if t >= hi * 0.9999)
    inside = [t for t in ticks if first <= t <= last]
    return inside if len(inside) >= 2 else [10.0**k0, 10.0**k1]


def _count_ticks(top: int) -> list[float]:
    """Integer ticks from 0 covering ``top`` (a count axis has no 2.5 steps)."""
    step = max(1, math.ceil(nice_ticks(0.0, float(max(top, 1)), 5)[1]))
    return [float(k * step) for k in range(math.ceil(max(top, 1) / step) + 1)]


class _Axes:
    """Maps data to pixel coordinates; linear x, linear or log10 y."""

    def __init__(
        self,
        x_ticks: list[float],
        y_ticks: list[float],
        log_y: bool,
        size_px: tuple[int, int] = (WIDTH_PX, HEIGHT_PX),
    ) -> None:
        self.width, self.height = size_px
        self.x0, self.x1 = x_ticks[0], x_ticks[-1]
        self.log_y = log_y
        self.y0, self.y1 = self._ty(y_ticks[0]), self._ty(y_ticks[-1])
        self.left, self.right = _MARGIN_LEFT, self.width - _MARGIN_RIGHT
        self.top, self.bottom = _MARGIN_TOP, self.height - _MARGIN_BOTTOM

    def _ty(self, y: float) -> float:
        return math.log10(y) if self.log_y else y

    def px(self, x: float) -> float:
        span = self.x1 - self.x0 or 1.0
        return self.left + (x - self.x0) / span * (self.right - self.left)

    def py(self, y: float) -> float:
        span = self.y1 - self.y0 or 1.0
        return self.bottom - (self._ty(y) - self.y0) / span * (self.bottom - self.top)


def _frame(
    ax: _Axes, x_ticks: list[float], y_ticks: list[float], x_label: str, y_label: str
) -> list[str]:
    """Grid, tick labels, axis lines and axis labels."""
    out: list[str] = []
    x_step = x_ticks[1] - x_ticks[0]
    for t in x_ticks:
        x = ax.px(t)
        out.append(
            f'<line class="chart-grid" x1="{x:.1f}" y1="{ax.top}" x2="{x:.1f}" y2="{ax.bottom}"/>'
            f'<text class="chart-tick" x="{x:.1f}" y="{ax.bottom + 16}" text-anchor="middle">'
            f"{format_tick(t, x_step)}</text>"
        )
    y_step = y_ticks[1] - y_ticks[0]
    for t in y_ticks:
        y = ax.py(t)
        label = format_tick(t, t if ax.log_y else y_step)
        out.append(
            f'<line class="chart-grid" x1="{ax.left}" y1="{y:.1f}" x2="{ax.right}" y2="{y:.1f}"/>'
            f'<text class="chart-tick" x="{ax.left - 6}" y="{y + 4:.1f}" text-anchor="end">'
            f"{label}</text>"
        )
    mid_y = (ax.top + ax.bottom) / 2
    out.append(
        f'<rect class="chart-axes" x="{ax.left}" y="{ax.top}" width="{ax.right - ax.left}" '
        f'height="{ax.bottom - ax.top}"/>'
        f'<text class="chart-label" x="{(ax.left + ax.right) / 2:.1f}" y="{ax.height - 8}" '
        f'text-anchor="middle">{escape(x_label)}</text>'
        f'<text class="chart-label" transform="translate(16 {mid_y:.1f}) rotate(-90)" '
        f'text-anchor="middle">{escape(y_label)}</text>'
    )
    return out


def _legend(labels: Sequence[tuple[str, str, str]], right: float) -> list[str]:
    """Legend in the top margin, right-aligned: (label, css class, key) triples; the key is
    drawn as a ``"line"``, a ``"dot"`` or a histogram ``"box"``."""
    out: list[str] = []
    x = right
    for label, css, kind in reversed(labels):
        width = 34 + 7 * len(label)
        x -= width
        keys = {
            "dot": f'<circle class="{css} marker legend-key" cx="{x + 12:.1f}" cy="14" r="3"/>',
            "box": f'<polyline class="{css} hist legend-key" points="{x + 4:.1f},20 {x + 4:.1f},8 '
            f'{x + 20:.1f},8 {x + 20:.1f},20"/>',
            "line": f'<line class="{css} legend-key" x1="{x:.1f}" y1="14" '
            f'x2="{x + 24:.1f}" y2="14"/>',
        }
        key = keys[kind]
        out.append(
            f'{key}<text class="chart-legend" x="{x + 29:.1f}" y="18">{escape(label)}</text>'
        )
    return out


def _open(chart_id: str, title: str, desc: str, ax: _Axes) -> str:
    return (
        f'<svg class="chart" id="{escape(chart_id)}" role="img" viewBox="0 0 {ax.width} '
        f'{ax.height}" xmlns="http://www.w3.org/2000/svg" aria-labelledby="{escape(chart_id)}-t '
        f'{escape(chart_id)}-d"><title id="{escape(chart_id)}-t">{escape(title)}</title>'
        f'<desc id="{escape(chart_id)}-d">{escape(desc)}</desc>'
    )


def line_chart(
    chart_id: str,
    title: str,
    series: Sequence[Series],
    x_label: str,
    y_label: str,
    *,
    log_y: bool = False,
    zero_line: bool = False,
    size_px: tuple[int, int] = (WIDTH_PX, HEIGHT_PX),
) -> str:
    """An SVG line chart of one or more series.

    Parameters
    ----------
    chart_id : str
        The ``id`` of the ``<svg>`` element (unique in the page).
    title : str
        Accessible title (``<title>``); the visible caption is the page's ``<figcaption>``.
    series : sequence of Series
        At least one series with a finite point.
    x_label, y_label : str
        Axis labels, with the unit, e.g. ``"residual [mm]"``.
    log_y : bool
        Log10 y axis; non-positive values are dropped.
    zero_line : bool
        Emphasise y = 0.
    size_px : (int, int)
        Width and height of the ``viewBox`` (the chart scales to its container).

    Raises
    ------
    ValueError
        No finite point to draw.
    """
    clean: list[tuple[Series, FloatArray, FloatArray]] = []
    for s in series:
        x, y = np.asarray(s.x, dtype=float), np.asarray(s.y, dtype=float)
        keep = np.isfinite(x) & np.isfinite(y) & ((y > 0) if log_y else True)
        clean.append((s, x[keep], y[keep]))
    xs = np.concatenate([c[1] for c in clean]) if clean else np.empty(0)
    ys = np.concatenate([c[2] for c in clean]) if clean else np.empty(0)
    if xs.size == 0:
        raise ValueError(f"line_chart {chart_id!r}: no finite point to draw")
    x_ticks = nice_ticks(float(xs.min()), float(xs.max()), 8)
    lo, hi = float(ys.min()), float(ys.max())
    y_ticks = _log_ticks(lo, hi) if log_y else nice_ticks(min(lo, 0.0) if zero_line else lo, hi)
    ax = _Axes(x_ticks, y_ticks, log_y, size_px)
    parts = [_open(chart_id, title, f"{y_label} against {x_label}", ax)]
    parts += _frame(ax, x_ticks, y_ticks, x_label, y_label)
    if zero_line and not log_y and y_ticks[0] <= 0 <= y_ticks[-1]:
        parts.append(
            f'<line class="chart-zero" x1="{ax.left}" y1="{ax.py(0):.1f}" x2="{ax.right}" '
            f'y2="{ax.py(0):.1f}"/>'
        )
    for s, x, y in clean:
        pts = " ".join(f"{ax.px(a):.1f},{ax.py(b):.1f}" for a, b in zip(x, y, strict=True))
        if s.line:
            parts.append(f'<polyline class="{escape(s.css_class)}" points="{pts}"/>')
        if s.markers or not s.line:
            parts += [
                f'<circle class="{escape(s.css_class)} marker" cx="{ax.px(a):.1f}" '
                f'cy="{ax.py(b):.1f}" r="{2.0 if x.size <= 400 else 1.4}"/>'
                for a, b in zip(x, y, strict=True)
            ]
    parts += _legend(
        [(s.label, s.css_class, "line" if s.line else "dot") for s in series], ax.right
    )
    parts.append("</svg>")
    return "".join(parts)


def histogram_chart(
    chart_id: str,
    title: str,
    data: Sequence[tuple[str, FloatArray, str]],
    x_label: str,
    *,
    bins: int = 30,
    size_px: tuple[int, int] = (WIDTH_PX, HEIGHT_PX),
) -> str:
    """Overlaid step histograms on common bins.

    Parameters
    ----------
    data : sequence of (label, values, css class)
        Values in the x axis unit (e.g. mm), shape (n,) each; non-finite values dropped.
    bins : int
        Number of equal-width bins over the pooled range.
    size_px : (int, int)
        Width and height of the ``viewBox``.

    Raises
    ------
    ValueError
        No finite value, or ``bins < 1``.
    """
    if bins < 1:
        raise ValueError(f"bins: must be at least 1, got {bins}")
    cleaned = [(lbl, np.asarray(v, dtype=float), css) for lbl, v, css in data]
    cleaned = [(lbl, v[np.isfinite(v)], css) for lbl, v, css in cleaned]
    pooled = np.concatenate([v for _, v, _ in cleaned]) if cleaned else np.empty(0)
    if pooled.size == 0:
        raise ValueError(f"histogram_chart {chart_id!r}: no finite value to draw")
    x_ticks = nice_ticks(float(pooled.min()), float(pooled.max()), 8)
    edges = np.linspace(x_ticks[0], x_ticks[-1], bins + 1)
    counts = [np.histogram(v, bins=edges)[0] for _, v, _ in cleaned]
    y_ticks = _count_ticks(max(int(c.max()) for c in counts))
    ax = _Axes(x_ticks, y_ticks, False, size_px)
    sizes = "; ".join(f"{lbl}: n = {v.size}" for lbl, v, _ in cleaned)
    desc = f"number of samples per bin of {x_label}, {bins} bins; {sizes}"
    parts = [_open(chart_id, title, desc, ax)]
    parts += _frame(ax, x_ticks, y_ticks, x_label, "samples per bin [count]")
    for (_, _, css), c in zip(cleaned, counts, strict=True):
        pts = [f"{ax.px(edges[0]):.1f},{ax.py(0):.1f}"]
        for k in range(bins):
            pts.append(f"{ax.px(edges[k]):.1f},{ax.py(c[k]):.1f}")
            pts.append(f"{ax.px(edges[k + 1]):.1f},{ax.py(c[k]):.1f}")
        pts.append(f"{ax.px(edges[-1]):.1f},{ax.py(0):.1f}")
        parts.append(f'<polyline class="{escape(css)} hist" points="{" ".join(pts)}"/>')
    parts += _legend([(lbl, css, "box") for lbl, _, css in cleaned], ax.right)
    parts.append("</svg>")
    return "".join(parts)
