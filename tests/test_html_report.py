"""The HTML calibration report (calib/html_report): content, escaping, charts, and a
headless-browser check that it renders offline with every section and chart visible."""

from __future__ import annotations

import copy
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from browser import offline_page, require_chromium

from calib.dataset import SampleSet, make_samples, parse_samples_csv
from calib.html_report import SECTIONS, render_report_html, sample_residuals
from calib.html_report.fmt import num_fixed, num_sci, num_sig
from calib.html_report.svg import Series, format_tick, histogram_chart, line_chart, nice_ticks
from calib.identify import IdentifyOptions, identify, split_rows
from calib.models import builtin_model
from calib.synthetic import make_true_cell, random_poses_deg

MODEL = builtin_model("hsr-jr680")
DATA = Path(__file__).resolve().parents[1] / "calib" / "data" / "hsr-robotcali.csv"
CHART_IDS = (
    "chart-residuals-before",
    "chart-residuals-after",
    "chart-histogram-before",
    "chart-histogram-after",
    "chart-convergence",
)


@pytest.fixture(scope="module")
def real_case() -> tuple[dict[str, Any], SampleSet]:
    """LM by maximum likelihood (--no-prior) on the first 120 real rows, 20 % random hold-out:
    implausible parameters (the default MAP fit is plausible on them)."""
    samples = parse_samples_csv(DATA.read_text()).subset(np.arange(120))
    result = identify(MODEL, samples, IdentifyOptions(method="lm", prior=False)).to_json()
    return result, samples


@pytest.fixture(scope="module")
def synthetic_case() -> tuple[dict[str, Any], SampleSet]:
    """An emulated cell, spread poses, no hold-out, prior on: a plausible fit."""
    cell = make_true_cell(MODEL)
    rng = np.random.default_rng(3)
    q = random_poses_deg(cell, 120, rng)
    samples = make_samples(q, cell.lengths_mm(q) + rng.normal(0, 0.05, 120))
    result = identify(MODEL, samples, IdentifyOptions(prior=True, test_fraction=0)).to_json()
    return result, samples


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


# ----------------------------------------------------------------------------- residuals
def test_after_residuals_reproduce_the_results_train_and_test_rmse(real_case) -> None:
    result, samples = real_case
    res = sample_residuals(result, samples)
    train, test = split_rows(samples, 0.2, 0, "random", 10)
    after = result["metrics"]["after"]
    assert _rms(res.after_mm[train]) == pytest.approx(after["train"]["rmse_mm"], rel=1e-9)
    assert _rms(res.after_mm[test]) == pytest.approx(after["test"]["rmse_mm"], rel=1e-9)


def test_before_residuals_match_the_before_model_when_fitted_on_the_same_rows(
    synthetic_case,
) -> None:
    result, samples = synthetic_case
    res = sample_residuals(result, samples)
    assert res.before_mm is not None
    before = result["metrics"]["before"]["train"]["rmse_mm"]
    assert _rms(res.before_mm) == pytest.approx(before, rel=1e-6)
    assert _rms(res.before_mm) > 10 * _rms(res.after_mm)


def test_unknown_robot_gives_after_residuals_only_and_says_why(synthetic_case) -> None:
    result, samples = synthetic_case
    custom = {**result, "robot": "my-<custom>-robot"}
    res = sample_residuals(custom, samples)
    assert res.before_mm is None
    assert "not a built-in model" in res.before_note
    html = render_report_html(custom, res)
    assert "my-&lt;custom&gt;-robot" in html and "chart-residuals-after" in html
    assert "chart-residuals-before" not in html


# ------------------------------------------------------------------------------- content
def test_every_section_and_chart_is_present_and_nothing_external(real_case) -> None:
    result, samples = real_case
    html = render_report_html(result, sample_residuals(result, samples), source="r.json")
    for sid, title in SECTIONS:
        assert f'<section id="{sid}"' in html, sid
        assert title in html
    for cid in CHART_IDS:
        assert html.count(f'<svg class="chart" id="{cid}"') == 1, cid
    assert "<script" not in html.lower()
    # The only URL is the SVG namespace; no src/href to anywhere.
    urls = set(re.findall(r"https?://[^\s\"'<>)]+", html))
    assert urls == {"http://www.w3.org/2000/svg"}
    assert not re.search(r"\b(src|href)\s*=", html)
    assert "@media print" in html and "@page" in html


def test_numbers_have_sensible_precision_and_units(real_case) -> None:
    result, samples = real_case
    html = render_report_html(result, sample_residuals(result, samples))
    visible = re.sub(r"<svg.*?</svg>", "", html, flags=re.S)  # chart coordinates aside
    visible = re.sub(r"<style>.*?</style>", "", visible, flags=re.S)
    long_decimals = re.findall(r"\d\.\d{6,}", visible)
    assert long_decimals == []
    after_test = result["metrics"]["after"]["test"]["rmse_mm"]
    assert f"{after_test:.3f}" in html
    for header in ("RMSE [mm]", "MAE [mm]", "MAX [mm]", "α [deg]", "Δa ± 1σ [mm]"):
        assert header in html
    charts = re.findall(r'<svg class="chart" id="([^"]+)".*?</svg>', html, flags=re.S)
    assert sorted(charts) == sorted(CHART_IDS)
    for svg in re.findall(r'<svg class="chart".*?</svg>', html, flags=re.S):
        labels = re.findall(r'class="chart-label"[^>]*>([^<]*)<', svg)
        assert len(labels) == 2, labels  # x and y
        dimensionless = {"iteration", "sample index (0-based data row)"}
        assert all(re.search(r"\[[^\]]+\]", lab) for lab in labels if lab not in dimensionless)


def test_implausible_rows_are_highlighted_and_plausible_ones_are_not(synthetic_case) -> None:
    result, _ = synthetic_case
    assert result["plausibility"]["plausible"]
    html = render_report_html(result)
    assert 'class="implausible"' not in html
    assert "NOT plausible" not in html
    bad = copy.deepcopy(result)
    for item in bad["plausibility"]["parameters"]:
        if item["name"] == "a3":
            item["ok"] = False
    bad["plausibility"]["plausible"] = False
    html = render_report_html(bad)
    dh_rows = re.findall(r'<tr( class="implausible")?><th scope="row">(\d)</th>', html)
    assert [j for cls, j in dh_rows if cls] == ["3", "3"]  # calibrated and error tables
    assert "NOT plausible" in html and 'aria-label="implausible">⚠' in html


def test_real_data_lists_unidentifiable_parameters_with_reasons(real_case) -> None:
    result, _ = real_case
    html = render_report_html(result)
    reasons = result["identifiability"]["reasons"]
    assert reasons
    for name, why in reasons.items():
        assert f"<code>{name}</code>" in html
        assert why.replace("'", "&#x27;") in html
    assert "Pass the data file" in html  # no samples given: the residual section says how
    assert "chart-residuals" not in html and "chart-histogram" not in html


def test_tcp_uncertainty_shown_when_present_else_not_computed(synthetic_case) -> None:
    result, _ = synthetic_case
    absent = {k: v for k, v in result.items() if k != "tcp_uncertainty_mm"}
    assert "not computed" in render_report_html(absent)
    html = render_report_html({**result, "tcp_uncertainty_mm": {"rms": 0.0123456, "max": 0.05}})
    assert "not computed" not in html
    assert ">0.012<" in html and ">0.050<" in html


def test_every_string_from_the_result_is_escaped(synthetic_case) -> None:
    result, _ = synthetic_case
    evil = "<img src=x onerror=alert(1)>"
    hostile = {
        **result,
        "robot": evil,
        "method": evil,
        "message": evil,
        "notes": [evil],
        "robust": evil,
        "identifiability": {
            **result["identifiability"],
            "unidentifiable": [evil],
            "reasons": {evil: evil},
        },
    }
    html = render_report_html(hostile, source=evil)
    assert "<img" not in html
    assert "&lt;img src=x onerror=alert(1)&gt;" in html


def test_partial_result_still_renders_and_says_what_is_missing() -> None:
    html = render_report_html({"robot": "r", "method": "lm"})
    assert "No metrics in this result" in html
    assert "No DH table" in html and "No cost history" in html
    with pytest.raises(TypeError, match="result"):
        render_report_html([1, 2])  # type: ignore[arg-type]


# ---------------------------------------------------------------------------- svg, format
@pytest.mark.parametrize(("lo", "hi"), [(0.0, 1.0), (-0.37, 1.22), (3.2, 3.2), (0, 1234.5)])
def test_nice_ticks_cover_the_range_with_round_steps(lo: float, hi: float) -> None:
    ticks = nice_ticks(lo, hi)
    assert ticks[0] <= lo and ticks[-1] >= hi and len(ticks) >= 2
    steps = np.diff(ticks)
    assert np.allclose(steps, steps[0])
    mantissa = steps[0] / 10 ** np.floor(np.log10(steps[0]))
    assert any(np.isclose(mantissa, m) for m in (1, 2, 2.5, 5))
    assert all(len(format_tick(t, steps[0])) <= 7 for t in ticks)


def test_number_formats() -> None:
    assert num_fixed(0.30000000000000004) == "0.300"
    assert num_fixed(-0.0001) == "0.000"
    assert num_fixed(-1.5, 1) == "−1.5"
    assert num_fixed(float("nan")) == "—" and num_fixed(None) == "—"
    assert num_sig(0.0041234) == "0.0041" and num_sig(798.19) == "800"
    assert num_sci(1.4151689e25) == "1.42 × 10<sup>25</sup>"


def test_charts_refuse_empty_data_and_count_every_sample() -> None:
    with pytest.raises(ValueError, match="no finite point"):
        line_chart("c", "t", [Series("s", np.array([np.nan]), np.array([1.0]), "x")], "x", "y")
    with pytest.raises(ValueError, match="no finite value"):
        histogram_chart("h", "t", [("s", np.array([]), "x")], "x")
    values = np.random.default_rng(0).normal(0, 1, 500)
    edges_svg = histogram_chart("h", "t", [("s", values, "series-after")], "v [mm]", bins=20)
    assert "20 bins; s: n = 500" in edges_svg and "v [mm]" in edges_svg
    data_lines = re.findall(r'<polyline class="series-after hist" points="([^"]+)"', edges_svg)
    assert [len(p.split()) for p in data_lines] == [2 + 2 * 20]  # two corners per bin


# ------------------------------------------------------------------------------- browser
def test_report_renders_offline_in_chromium(real_case, tmp_path: Path) -> None:
    require_chromium()
    result, samples = real_case
    report = tmp_path / "report.html"
    report.write_text(
        render_report_html(result, sample_residuals(result, samples), source="real-120.json"),
        encoding="utf-8",
    )
    with offline_page() as (page, log):
        page.goto(report.as_uri())
        page.wait_for_load_state("load")
        for sid, _ in SECTIONS:
            assert page.locator(f"section#{sid}").is_visible(), sid
        for cid in CHART_IDS:
            chart = page.locator(f"svg#{cid}")
            assert chart.is_visible(), cid
            box = chart.bounding_box()
            assert box is not None and box["width"] > 400 and box["height"] > 120, cid
            # Every sample is a dot in the residual charts; one line per other chart, and
            # one per fit in the convergence chart (robust rounds restart the curve).
            drawn = "circle.marker" if "residuals" in cid else "polyline"
            fits = len(result.get("cost_history_fit_starts") or [0])
            lines = fits if cid == "chart-convergence" else 1
            expected = len(samples) if "residuals" in cid else lines
            assert chart.locator(f"{drawn}:not(.legend-key)").count() == expected, cid
            assert chart.locator(".legend-key").count() == lines, cid
        assert page.locator("tr.implausible").count() >= 1
        page.screenshot(path=str(tmp_path / "report.png"), full_page=True)
        page.emulate_media(media="print")
        page.pdf(path=str(tmp_path / "report.pdf"), format="A4")
    assert log.console_errors == [] and log.page_errors == []
    assert log.blocked_requests == []
    assert (tmp_path / "report.png").stat().st_size > 10_000
    assert (tmp_path / "report.pdf").stat().st_size > 10_000


def test_browser_gate_blocks_and_records_requests_to_other_hosts(tmp_path: Path) -> None:
    """The harness itself: a page that reaches out is caught (so the check above can fail)."""
    require_chromium()
    page_file = tmp_path / "leaky.html"
    page_file.write_text(
        '<!DOCTYPE html><html><head><link rel="stylesheet" href="http://example.invalid/a.css">'
        '</head><body><img src="https://cdn.example.invalid/b.png" alt="x"></body></html>'
    )
    with offline_page() as (page, log):
        page.goto(page_file.as_uri())
        page.wait_for_load_state("load")
    assert sorted(log.blocked_requests) == [
        "http://example.invalid/a.css",
        "https://cdn.example.invalid/b.png",
    ]


def test_drift_wording_is_the_results_one_and_a_method_without_drift_says_so(
    synthetic_case,
) -> None:
    """Issue 27 item 4: ukf-vslm does not model drift: the result's ``drift.summary`` (the
    line the operator page shows) says it was not looked for, and the report shows that same
    line, never "held still" or "no step and no drift found"."""
    result, samples = synthetic_case
    ukf = identify(MODEL, samples, IdentifyOptions(method="ukf-vslm", test_fraction=0)).to_json()
    summary = ukf["drift"]["summary"]
    assert "ukf-vslm" in summary and "not looked for" in summary and "held still" not in summary
    html = render_report_html(ukf)
    section = html[html.index('id="drift"') :]
    section = section[: section.index("</section>")]
    assert summary in section
    assert "held still" not in section and "No step and no drift" not in section
    # a method that models drift and found none: the same line in the report as in the result
    lm = result["drift"]
    assert lm["model"] == "none" and lm["summary"] in render_report_html(result)
