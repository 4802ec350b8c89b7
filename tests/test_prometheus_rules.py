"""The plant's monitoring files: Prometheus alert rules (``deploy/prometheus/``, unit-tested
with Prometheus's own ``promtool test rules``) and the Grafana dashboard
(``deploy/grafana/cablecal.json``); both may reference only metrics the daemon exports."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path
from typing import Any

import pytest
import yaml

from daemon.metrics import REGISTRY

ROOT = Path(__file__).resolve().parents[1]
RULES = ROOT / "deploy/prometheus/cablecal-rules.yml"
RULE_TESTS = ROOT / "deploy/prometheus/cablecal-rules.test.yml"
DASHBOARD = ROOT / "deploy/grafana/cablecal.json"
PROMTOOL = shutil.which("promtool")
needs_promtool = pytest.mark.skipif(
    PROMTOOL is None, reason="promtool is not installed (Debian package prometheus; .ci/run)"
)
#: Series Prometheus makes itself for every target.
PROMETHEUS_OWN = {"up"}
#: PromQL words that look like metric names: functions, aggregations, keywords.
PROMQL_WORDS = {
    "sum",
    "rate",
    "increase",
    "by",
    "without",
    "unless",
    "and",
    "or",
    "on",
    "ignoring",
    "histogram_quantile",
    "max",
    "min",
    "avg",
    "count",
    "le",
    "label_values",
    "group_left",
}


def exported_names() -> set[str]:
    """Every series name the daemon's registry can expose (counters as ``_total``,
    histograms as ``_bucket``/``_sum``/``_count``)."""
    names: set[str] = set()
    for family in REGISTRY.collect():
        if family.type == "counter":
            names |= {family.name + "_total", family.name + "_created"}
        elif family.type == "histogram":
            names |= {family.name + s for s in ("_bucket", "_sum", "_count", "_created")}
        else:
            names.add(family.name)
    return names


def metric_names(expr: str) -> set[str]:
    """Metric names of a PromQL expression: identifiers not inside ``{...}`` label matchers,
    quotes or ``[...]`` ranges, and not PromQL functions or keywords."""
    stripped = re.sub(r'"[^"]*"', "", expr)
    stripped = re.sub(r"\{[^}]*\}|\[[^\]]*\]", " ", stripped)
    # Label lists: by (...), without (...), on (...), ignoring (...), group_left (...).
    stripped = re.sub(
        r"\b(by|without|on|ignoring|group_left|group_right)\s*\([^)]*\)", " ", stripped
    )
    # Grafana's label_values(metric, label): the second argument is a label.
    stripped = re.sub(r"label_values\(\s*([A-Za-z_:][\w:]*)\s*,\s*\w+\s*\)", r"\1", stripped)
    words = set(re.findall(r"[A-Za-z_:][A-Za-z0-9_:]*", stripped))
    return {w for w in words if w not in PROMQL_WORDS and not w.startswith("$")}


def rules() -> list[dict[str, Any]]:
    data = yaml.safe_load(RULES.read_text())
    return [r for group in data["groups"] for r in group["rules"]]


def dashboard_exprs() -> list[str]:
    dash = json.loads(DASHBOARD.read_text())
    exprs = [t["expr"] for p in dash["panels"] for t in p["targets"]]
    exprs += [v["definition"] for v in dash["templating"]["list"] if "definition" in v]
    return exprs


def test_metric_names_are_parsed_from_promql() -> None:
    expr = (
        'sum by (instance, device) (rate(cablecal_device_errors_total{role="robot"}[5m])) '
        "> 0 unless cablecal_device_polls_total"
    )
    assert metric_names(expr) == {"cablecal_device_errors_total", "cablecal_device_polls_total"}


def test_rules_and_dashboard_use_only_exported_metrics() -> None:
    known = exported_names() | PROMETHEUS_OWN
    assert "cablecal_sensor_moved_total" in known and "cablecal_hold_check_rms_mm" in known
    used_rules = set().union(*(metric_names(r["expr"]) for r in rules()))
    used_dash = set().union(*(metric_names(e) for e in dashboard_exprs()))
    assert used_rules - known == set()
    assert used_dash - known == set()
    # The dashboard shows what the issue asks for: hold checks per robot, poll rates, device errors.
    for name in (
        "cablecal_hold_check_rms_mm",
        "cablecal_device_polls_total",
        "cablecal_device_errors_total",
    ):
        assert name in used_dash


def test_the_alerts_cover_the_plant_s_failures() -> None:
    alerts = {r["alert"]: r for r in rules()}
    assert {
        "CablecalHoldCheckOverThreshold",
        "CablecalSensorMoved",
        "CablecalDeviceStale",
        "CablecalDeviceDown",
        "CablecalUncleanShutdown",
        "CablecalIdentificationFailed",
    } <= set(alerts)
    for name, rule in alerts.items():
        assert rule["labels"]["severity"] in ("warning", "critical"), name
        assert rule["annotations"]["summary"], name


@needs_promtool
def test_promtool_checks_and_unit_tests_pass() -> None:
    assert PROMTOOL is not None
    for args in (["check", "rules", RULES.name], ["test", "rules", RULE_TESTS.name]):
        proc = subprocess.run(
            [PROMTOOL, *args],
            cwd=RULES.parent,
            capture_output=True,
            text=True,
            timeout=60,
            check=False,
        )
        assert proc.returncode == 0, proc.stdout + proc.stderr
        assert "SUCCESS" in proc.stdout + proc.stderr
    tests = yaml.safe_load(RULE_TESTS.read_text())["tests"]
    tested = {t["alertname"] for case in tests for t in case["alert_rule_test"]}
    assert tested == {r["alert"] for r in rules()}  # every alert has a unit test
