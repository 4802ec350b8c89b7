"""CSV parsing and model files: every error names the row/field."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from calib.dataset import SampleError, capture_times_s, parse_samples_csv, samples_to_csv
from calib.models import ModelError, builtin_model, model_from_mapping, parse_model_text
from daemon.datafiles import bundled_dataset_text, read_samples

HEADER = "Q1,q2,q3,q4,q5,q6,L,x\n"
ROW = "1,2,3,4,5,6,350.5,9\n"


def test_header_is_case_insensitive_and_extra_columns_ignored() -> None:
    s = parse_samples_csv(HEADER + ROW + ROW)
    assert s.joints_deg.shape == (2, 6)
    assert s.length_mm.tolist() == [350.5, 350.5]
    assert s.anchor == ("A", "A")


@pytest.mark.parametrize(
    ("text", "pattern"),
    [
        ("q1,q2,q3,q4,q5,L\n1,2,3,4,5,6\n", r"row 1: missing column\(s\) \['q6'\]"),
        ("q1,q2,q3,q4,q5,q6\n1,2,3,4,5,6\n", "missing column 'L'"),
        (HEADER + ROW + "1,2,x3,4,5,6,350,0\n", r"row 3, column 'q3': not a number"),
        (HEADER + "1,2,3,4,5,nan,350,0\n", r"row 2, column 'q6': not a finite number"),
        (HEADER + "1,2,3,4,5,6,2000.5,0\n", r"row 2, column 'L': .*outside the sensor range"),
        (HEADER + "1,2,3,4,5,6,-1,0\n", r"row 2, column 'L'"),
        (HEADER + "1,2,3\n", r"row 2, column 'q4': missing value"),
        ("", "empty"),
        (HEADER, "no data rows"),
    ],
)
def test_bad_csv_names_row_and_column(text: str, pattern: str) -> None:
    with pytest.raises(SampleError, match=pattern):
        parse_samples_csv(text)


def test_csv_round_trip_keeps_anchor_and_values() -> None:
    s = parse_samples_csv("q1,q2,q3,q4,q5,q6,L,anchor\n1,2,3,4,5,6,100,A\n1,2,3,4,5,7,200,B\n")
    again = parse_samples_csv(samples_to_csv(s))
    np.testing.assert_allclose(again.joints_deg, s.joints_deg)
    assert again.anchor == ("A", "B")
    assert again.anchor_ids == ("A", "B")


def test_bundled_dataset_is_the_published_one() -> None:
    s = parse_samples_csv(bundled_dataset_text())
    assert len(s) == 2017
    assert s.length_mm.min() == pytest.approx(291.7, abs=0.1)
    assert s.joints_deg[:, 5].max() - s.joints_deg[:, 5].min() < 0.01  # q6 constant


def test_read_samples_reports_missing_file(tmp_path: Path) -> None:
    with pytest.raises(SampleError, match="cannot read"):
        read_samples(tmp_path / "nope.csv")


def test_example_toml_equals_builtin_model() -> None:
    text = (Path(__file__).parent.parent / "examples" / "hsr-jr680.toml").read_text()
    from_file = parse_model_text(text, "toml")
    builtin = builtin_model("hsr-jr680")
    np.testing.assert_array_equal(from_file.dh_table, builtin.dh_table)
    assert from_file.joint_limits_deg is not None and builtin.joint_limits_deg is not None
    np.testing.assert_array_equal(from_file.joint_limits_deg, builtin.joint_limits_deg)
    again = parse_model_text(json.dumps(builtin.to_dict()), "json")
    np.testing.assert_array_equal(again.dh_table, builtin.dh_table)


@pytest.mark.parametrize(
    ("mutate", "field"),
    [
        (lambda d: d["joints"][2].update(a_mm="x"), "joints[3].a_mm"),
        (lambda d: d["joints"][0].pop("d_mm"), "joints[1].d_mm"),
        (lambda d: d.update(convention="euler"), "convention"),
        (lambda d: d["joints"].pop(), "joints"),
        (lambda d: d.update(tool_mm=[1, 2]), "tool_mm"),
        (lambda d: d["joints"][4].update(limits_deg=[10, -10]), "joints[5].limits_deg"),
        (lambda d: d.update(colour="red"), "colour"),
    ],
)
def test_bad_model_names_the_field(mutate, field: str) -> None:
    data = builtin_model("hsr-jr680").to_dict()
    mutate(data)
    with pytest.raises(ModelError) as info:
        model_from_mapping(data)
    assert info.value.field == field


def test_toml_syntax_error_is_a_model_error() -> None:
    with pytest.raises(ModelError, match="syntax"):
        parse_model_text("name = ", "toml")


def test_capture_times_count_only_for_live_captures_in_order() -> None:
    """calib's rule for the drift model's time axis: seconds since the first sample when
    every sample was captured live, has its time and the times never go back; else None."""
    times = capture_times_s([100.0, 101.5, 101.5, 104.0], [True] * 4)
    assert times is not None and times.tolist() == [0.0, 1.5, 1.5, 4.0]
    assert capture_times_s([100.0, 101.0], [True, False]) is None  # one imported
    assert capture_times_s([100.0, None], [True, True]) is None  # a time missing
    assert capture_times_s([101.0, 100.0], [True, True]) is None  # back in time
    assert capture_times_s([100.0], [True]) is None  # one sample has no time axis
