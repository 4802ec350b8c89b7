"""The typed result (calib/result.py): every shape of result.json written since the first
contract loads and works; a field of the wrong type is named; the JSON goes back unchanged.

The files in tests/data/ are ours, one per shape, written by tests/data/make_result_shapes.py
from the shapes ``git log -p`` of calib/identify.py and calib/report.py shows.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from calib.export import export_result
from calib.filter.correct import calibration_from_result
from calib.html_report import render_report_html
from calib.identify.result_json import drift_summary
from calib.models import builtin_model
from calib.predict import predict_lengths_from_result
from calib.result import RESULT_KEYS, RESULT_SHAPES, CalibrationResult, ResultError, shape_of

DATA = Path(__file__).resolve().parent / "data"
#: file → (shape, what it must have)
FILES = {
    "result_shape1_2026-11-21.json": 1,
    "result_shape2_2026-11-23.json": 2,
    "result_shape3_2026-11-23.json": 3,
    "result_shape4_2026-11-25.json": 4,
    "result_shape4_2026-11-28_daemon.json": 4,
}
POSES_DEG = np.array([[0.0, -20.0, 10.0, 5.0, 30.0, 0.0], [15.0, 10.0, -15.0, 0.0, 45.0, 20.0]])


def _doc(name: str) -> dict[str, Any]:
    doc: dict[str, Any] = json.loads((DATA / name).read_text(encoding="utf-8"))
    return doc


@pytest.mark.parametrize("name", list(FILES))
def test_every_shape_loads_and_gives_its_json_back(name: str) -> None:
    text = (DATA / name).read_text(encoding="utf-8")
    doc = json.loads(text)
    result = CalibrationResult.from_json(doc)
    assert result.shape == FILES[name]
    assert json.dumps(result.to_json(), indent=1) + "\n" == text  # byte for byte
    assert result.to_json() is not doc  # a copy: the caller's edits do not reach it
    assert len(result.dh_rows()) == 6 and result.robot == doc["robot"]
    assert (
        result.figures("after", "train")["rmse_mm"] == doc["metrics"]["after"]["train"]["rmse_mm"]
    )


@pytest.mark.parametrize("name", list(FILES))
def test_every_shape_predicts_exports_reports_and_corrects(name: str) -> None:
    result = CalibrationResult.from_json(_doc(name))
    lengths = predict_lengths_from_result(result, POSES_DEG)
    assert lengths.shape == (2,) and np.all(np.isfinite(lengths)) and np.all(lengths > 0)
    toml = export_result(result, "toml", builtin_model(result.robot or ""))
    assert f"Calibrated model of {result.robot!r}" in toml
    html = render_report_html(result)
    assert "No DH table" not in html and "No metrics" not in html
    cal = calibration_from_result(result, builtin_model(result.robot or ""))
    assert cal.covariance is not None and cal.covariance.shape == (4, 4)


def test_older_shapes_predict_as_the_newer_one_they_were_cut_from() -> None:
    """Shapes 1 to 3 hold the same fit: what they lack changes no prediction."""
    predicted = [
        predict_lengths_from_result(_doc(n), POSES_DEG)
        for n in list(FILES)[:3]  # shapes 1, 2, 3
    ]
    np.testing.assert_array_equal(predicted[0], predicted[1])
    np.testing.assert_array_equal(predicted[0], predicted[2])


def test_what_an_older_shape_lacks_is_absent_not_invented() -> None:
    first = CalibrationResult.from_json(_doc("result_shape1_2026-11-21.json"))
    assert first.tcp_uncertainty_mm is None and first.robust_detail is None
    assert first.drift is None and first.cost_history_fit_starts is None
    assert first.split is not None and first.split.test_rows is None
    assert first.prior is not None and set(first.prior.block) == {
        "used",
        "dh_mm",
        "dh_deg",
        "tool_mm",
        "noise_mm",
    }
    assert "not computed" in render_report_html(first)  # the TCP section says so


def test_a_drift_block_of_before_the_summary_is_worded_as_today() -> None:
    doc = _doc("result_shape4_2026-11-25.json")
    assert "summary" not in doc["drift"]
    result = CalibrationResult.from_json(doc)
    assert result.drift is not None
    assert result.drift.summary == drift_summary(doc["drift"])
    assert "indicator re-zeroed at row 45" in result.drift.summary
    html = render_report_html(result)
    assert '<td class="num">45</td><td>indicator re-zeroed</td>' in html


def test_the_daemons_fields_and_the_controller_block_load() -> None:
    doc = _doc("result_shape4_2026-11-28_daemon.json")
    result = CalibrationResult.from_json(doc)
    assert result.controller is not None and result.controller["maker"] == "fanuc"
    assert result.flagged_sample_ids == tuple(doc["flagged_sample_ids"])
    assert result.split is not None and result.split.test_sample_ids == tuple(
        doc["split"]["test_sample_ids"]
    )
    assert result.plan_check == doc["plan_check"]


def test_sample_ids_and_plan_check_are_added_as_the_daemon_stored_them() -> None:
    doc = _doc("result_shape4_2026-11-28_daemon.json")
    for key in ("flagged_sample_ids", "plan_check"):
        del doc[key]
    del doc["split"]["test_sample_ids"]
    ids = [1000 + i for i in range(doc["split"]["n_train"] + doc["split"]["n_test"])]
    out = CalibrationResult.from_json(doc).with_sample_ids(ids)
    out = CalibrationResult.from_json(out).with_plan_check({"plan_id": 3}, "stray")
    assert list(out)[-2:] == ["flagged_sample_ids", "plan_check"]
    assert out["split"]["test_sample_ids"] == [ids[i] for i in doc["split"]["test_rows"]]
    assert out["notes"][-1] == "stray" and out["notes"][:-1] == doc["notes"]
    assert "plan_check" not in doc and "test_sample_ids" not in doc["split"]  # not edited


def test_a_partial_result_loads_with_its_fields_absent() -> None:
    result = CalibrationResult.from_json({"robot": "r", "method": "lm"})
    assert result.shape == 0 and result.dh is None and result.anchors == {}
    with pytest.raises(ResultError, match=r"^dh: expected a list of six joint rows"):
        result.dh_rows()
    with pytest.raises(ResultError, match=r"^anchor_mm: missing"):
        result.anchor_fit()


@pytest.mark.parametrize(
    ("edit", "field"),
    [
        ({"tool_mm": [1.0, 2.0]}, r"tool_mm: must hold 3 numbers"),
        ({"convention": "craig"}, r"convention: must be 'dh' or 'mdh'"),
        ({"anchors": {"B": {"anchor_mm": [0, 0, 0]}}}, r"anchors\.B\.length_offset_mm"),
        ({"metrics": {"after": {"test": {"rmse_mm": "low"}}}}, r"metrics\.after\.test\.rmse_mm"),
        ({"flagged_samples": [1, "2"]}, r"flagged_samples\[1\]: must be an integer"),
        ({"success": "yes"}, r"success: must be true or false"),
        ({"notes": ["ok", 3]}, r"notes\[1\]: must be text"),
        ({"split": {"test_rows": [0.5]}}, r"split\.test_rows\[0\]"),
        ({"prior": {"noise_mm": True}}, r"prior\.noise_mm: must be a number"),
    ],
)
def test_a_field_of_the_wrong_type_is_named(edit: dict[str, Any], field: str) -> None:
    doc = _doc("result_shape4_2026-11-25.json") | edit
    with pytest.raises(ResultError, match=field):
        CalibrationResult.from_json(doc)


def test_a_dh_row_of_the_wrong_type_is_named_by_its_index() -> None:
    doc = _doc("result_shape2_2026-11-23.json")
    doc["dh"][2]["d_mm"] = None
    with pytest.raises(ResultError, match=r"dh\[2\]\.d_mm: must be a number, got None"):
        CalibrationResult.from_json(doc)
    with pytest.raises(TypeError, match="result: expected a mapping"):
        CalibrationResult.from_json([1, 2])  # type: ignore[arg-type]


def test_the_shapes_table_covers_every_key_identify_writes() -> None:
    doc = _doc("result_shape4_2026-11-28_daemon.json")
    assert set(doc) <= RESULT_KEYS
    assert [s.number for s in RESULT_SHAPES] == [1, 2, 3, 4]
    assert shape_of({k: 0 for k in RESULT_SHAPES[0].added}) == 1
    assert shape_of({k: 0 for s in RESULT_SHAPES[:3] for k in s.added}) == 3


def test_a_theta_shift_turns_one_joint_and_keeps_the_rest() -> None:
    result = CalibrationResult.from_json(_doc("result_shape3_2026-11-23.json"))
    shifted = result.with_theta_shift(2, 0.5)
    assert shifted.dh_rows()[2].theta_deg == result.dh_rows()[2].theta_deg + 0.5
    assert shifted.dh_rows()[:2] == result.dh_rows()[:2]
    assert shifted.to_json()["dh"][2]["theta_deg"] == shifted.dh_rows()[2].theta_deg


def test_a_second_anchor_and_a_key_of_a_newer_release_are_kept() -> None:
    doc = _doc("result_shape4_2026-11-25.json")
    first = predict_lengths_from_result(doc, POSES_DEG)
    doc["anchors"] = {"B": {"anchor_mm": doc["anchor_mm"], "length_offset_mm": 10.0}}
    doc["from_a_newer_release"] = {"x": 1}
    result = CalibrationResult.from_json(doc)
    assert result.anchor_ids() == ["A", "B"] and result.anchor_fit("B").length_offset_mm == 10.0
    at_b = predict_lengths_from_result(result, POSES_DEG, "B")
    np.testing.assert_allclose(at_b - first, 10.0 - doc["length_offset_mm"], rtol=0, atol=1e-9)
    with pytest.raises(ResultError, match=r"anchor: 'C' is not in the result \(\['A', 'B'\]\)"):
        result.anchor_fit("C")
    assert result.to_json()["from_a_newer_release"] == {"x": 1}
    assert list(result.to_json()) == list(doc)
