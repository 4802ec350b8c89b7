"""Self-contained HTML calibration report (issue 14, item 4).

``render_report_html(result, residuals)`` turns a parsed ``result.json`` (and optionally the
per-sample residuals from ``sample_residuals(result, samples)``) into one HTML string with
inline CSS and inline SVG charts: no script, no file or network access, opens offline and
prints on A4. Used by ``cablecal report`` and the daemon's ``/identifications/{id}/report.html``.
"""

from calib.html_report.render import SECTIONS, render_report_html
from calib.html_report.residuals import SampleResiduals, sample_residuals

__all__ = ["SECTIONS", "SampleResiduals", "render_report_html", "sample_residuals"]
