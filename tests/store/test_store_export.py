"""Importing parsed CSV into the store, exporting CSV and JSON, and ``cablecal db export``."""

from __future__ import annotations

import json
import sqlite3
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import typer
from _store_helpers import (
    ROBOT,
    csv_text,
    import_csv,
    make_capture,
    random_joints,
    replace_cell,
    sample_count,
)
from typer.testing import CliRunner

from calib.dataset import SampleError, make_samples, parse_samples_csv
from daemon.cli import db as cli_db
from daemon.store import SCHEMA_VERSION, Store, StoreNotFound


@pytest.mark.parametrize(
    ("column_index", "value", "column", "pattern"),
    [(3, "abc", "q4", "not a number"), (6, "2500", "L", "outside the sensor range")],
)
def test_import_csv_with_bad_row_37_stores_nothing(
    store: Store,
    campaign: dict[str, Any],
    column_index: int,
    value: str,
    column: str,
    pattern: str,
) -> None:
    text = replace_cell(csv_text(60), 37, column_index, value)
    with pytest.raises(SampleError, match=pattern) as err:
        import_csv(store, campaign["id"], text)
    assert (err.value.row, err.value.column) == (37, column)
    assert f"row 37, column '{column}'" in str(err.value)
    assert sample_count(store.path) == 0


def test_import_joint_limit_violation_names_row_and_column(
    store: Store, campaign: dict[str, Any]
) -> None:
    text = replace_cell(csv_text(20), 12, 2, "10.0")  # q3 limits of hsr-jr680: [60, 300]
    with pytest.raises(SampleError, match="outside the limits") as err:
        import_csv(store, campaign["id"], text)
    assert (err.value.row, err.value.column) == (12, "q3")
    assert sample_count(store.path) == 0


def test_import_samples_is_all_or_nothing(
    store: Store, campaign: dict[str, Any], monkeypatch: pytest.MonkeyPatch
) -> None:
    import daemon.store.samples as campaigns_module

    samples = parse_samples_csv(csv_text(50))
    real = campaigns_module._import_batches

    def second_batch_fails(*args: Any) -> Iterator[Any]:
        """The first batch (20 rows) is inserted, then the disk is full."""
        batches = real(*args)
        yield next(batches)
        raise sqlite3.OperationalError("database or disk is full")

    monkeypatch.setattr(campaigns_module, "IMPORT_BATCH_ROWS", 20)
    monkeypatch.setattr(campaigns_module, "_import_batches", second_batch_fails)
    with pytest.raises(sqlite3.OperationalError):
        store.import_samples(campaign["id"], samples)
    monkeypatch.undo()
    assert sample_count(store.path) == 0
    ids = store.import_samples(campaign["id"], samples)
    assert len(ids) == 50 and ids == sorted(ids)
    with pytest.raises(StoreNotFound, match="campaign 99"):
        store.import_samples(99, samples)


def test_import_of_a_sample_set_checks_values(store: Store, campaign: dict[str, Any]) -> None:
    samples = make_samples(
        np.array([[0, 0, 90, 0, 0, 0], [0, 0, 400, 0, 0, 0]], float), np.array([500.0, 600.0])
    )
    with pytest.raises(SampleError) as err:
        store.import_samples(campaign["id"], samples)
    assert (err.value.row, err.value.column) == (3, "q3")
    assert sample_count(store.path) == 0


def test_export_csv_round_trips_through_parse_samples_csv(
    store: Store, campaign: dict[str, Any]
) -> None:
    cid = campaign["id"]
    text = csv_text(30, seed=3, groups=True)
    imported = parse_samples_csv(text)
    ids = import_csv(store, cid, text)
    rng = np.random.default_rng(4)
    captured = random_joints(rng, 3)
    cap_rows = [
        store.store_capture(cid, make_capture(q, 700.0 + np.pi * k, anchor="B"))
        for k, q in enumerate(captured)
    ]
    store.set_excluded(ids[5], True, "outlier")

    samples, sample_ids = store.sample_set(cid)
    assert sample_ids == [i for i in ids if i != ids[5]] + [r["id"] for r in cap_rows]
    again = parse_samples_csv(store.export_csv(cid))
    assert len(again) == len(samples) == 32
    keep = [i for i in range(30) if i != 5]
    # Imported values have 3 decimals: the 6-decimal CSV reproduces them exactly.
    np.testing.assert_array_equal(again.joints_deg[:29], imported.joints_deg[keep])
    np.testing.assert_array_equal(again.length_mm[:29], imported.length_mm[keep])
    # Captured means carry full precision: equal to the CSV's 6 decimals.
    np.testing.assert_allclose(again.joints_deg[29:], captured, rtol=0, atol=5e-7)
    np.testing.assert_allclose(again.length_mm[29:], 700.0 + np.pi * np.arange(3), atol=5e-7)
    np.testing.assert_allclose(again.joints_deg, samples.joints_deg, rtol=0, atol=5e-7)
    assert again.anchor == samples.anchor == tuple(imported.anchor[i] for i in keep) + ("B",) * 3
    assert imported.group is not None and again.group is not None
    assert again.group == tuple(imported.group[i] for i in keep) + ("",) * 3
    assert samples.line_of(0) == 2


def test_export_csv_of_an_empty_campaign_is_the_header(
    store: Store, campaign: dict[str, Any]
) -> None:
    assert store.export_csv(campaign["id"]) == "q1,q2,q3,q4,q5,q6,L,anchor\n"
    assert store.poses_deg(campaign["id"]).shape == (0, 6)
    with pytest.raises(StoreNotFound):
        store.export_csv(99)


def test_export_json_has_campaign_robot_and_flagged_samples(
    store: Store, campaign: dict[str, Any]
) -> None:
    cid = campaign["id"]
    a = store.store_capture(cid, make_capture((0, 0, 90, 0, 0, 0), 500.0))
    import_csv(store, cid, csv_text(2))
    store.set_excluded(a["id"], True, "moved")
    data = store.export_json(cid, include_raw=True)
    json.dumps(data, allow_nan=False)  # strict JSON
    assert data["format"] == "cablecal-campaign" and data["schema_version"] == SCHEMA_VERSION
    assert data["campaign"]["id"] == cid and data["robot"]["name"] == ROBOT
    assert data["robot"]["model"]["joints"][0]["a_mm"] == 250.0
    first, second = data["samples"][0], data["samples"][1]
    assert first["excluded"] is True and first["excluded_reason"] == "moved"
    assert first["count"] == 3 and first["q1_std"] == 0.001 and len(first["raw_readings"]) == 3
    assert second["source"] == "import" and second["count"] is None and second["q1_std"] is None
    assert "raw_readings" not in store.export_json(cid)["samples"][0]


# -------------------------------------------------------------------------------- CLI
def test_cli_db_export_csv_and_json(
    tmp_path: Path, cli: typer.Typer, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv("CABLECAL_DB_PATH", raising=False)
    path = tmp_path / "db.sqlite3"
    with Store(path) as s:
        cid = s.create_campaign("line 3", s.ensure_builtin_robot(ROBOT)["id"])["id"]
        import_csv(s, cid, csv_text(12, groups=True))
        s.store_capture(cid, make_capture((1, 2, 90, 4, 5, 6), 654.321))
        expected_csv = s.export_csv(cid)
    runner = CliRunner()

    result = runner.invoke(cli, ["db", "export", str(cid), "--format", "csv", "--db", str(path)])
    assert result.exit_code == 0, result.output
    assert result.stdout == expected_csv
    assert len(parse_samples_csv(result.stdout)) == 13

    out = tmp_path / "out" / "c.json"
    out.parent.mkdir()
    result = runner.invoke(
        cli,
        ["db", "export", "line 3", "--format", "json", "--out", str(out), "--raw"],
        env={"CABLECAL_DB_PATH": str(path)},
    )
    assert result.exit_code == 0, result.output
    data = json.loads(out.read_text(encoding="utf-8"))
    assert data["campaign"]["name"] == "line 3" and len(data["samples"]) == 13
    assert len(data["samples"][-1]["raw_readings"]) == 3

    result = runner.invoke(cli, ["db", "export", "77", "--db", str(path)])
    assert result.exit_code == cli_db.EXIT_NOT_FOUND
    assert "campaign 77 not found" in result.output
    result = runner.invoke(cli, ["db", "export", "1", "--db", str(tmp_path / "none.sqlite3")])
    assert result.exit_code == cli_db.EXIT_DB_ERROR
    assert "no such database file" in result.output
    assert not (tmp_path / "none.sqlite3").exists()
    result = runner.invoke(cli, ["db", "export", "1", "--format", "xml", "--db", str(path)])
    assert result.exit_code == 2
