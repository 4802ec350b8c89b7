"""Exports: a calibrated model written as TOML/JSON loads back as the same model; the URDF's
forward kinematics (read by yourdfpy, an independent parser) equal ours."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yourdfpy

from calib.cable import N_KIN, ParamLayout, predict_lengths
from calib.dataset import make_samples
from calib.export import export_model, export_result, model_from_result, model_to_urdf
from calib.identify import IdentifyOptions, identify
from calib.kinematics import forward_frames, tool_position
from calib.models import RobotModel, builtin_model, parse_model_text
from calib.predict import predict_lengths_from_result
from calib.result import ResultError
from calib.synthetic import make_true_cell, noisy_lengths, random_poses_deg


@pytest.fixture(scope="module")
def nominal() -> RobotModel:
    return builtin_model("hsr-jr680")


@pytest.fixture(scope="module")
def result(nominal: RobotModel) -> dict[str, Any]:
    cell = make_true_cell(nominal)
    rng = np.random.default_rng(21)
    q = random_poses_deg(cell, 80, rng)
    samples = make_samples(q, noisy_lengths(cell, q, rng))
    return identify(nominal, samples, IdentifyOptions(method="lm", test_fraction=0.0)).to_json()


def _poses(model: RobotModel, n: int, seed: int) -> np.ndarray:
    assert model.joint_limits_deg is not None
    lo, hi = model.joint_limits_deg.T
    return np.random.default_rng(seed).uniform(lo, hi, size=(n, 6))


def _urdf_fk(path: Path, q_deg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Tool point [mm] and flange rotation per pose from yourdfpy."""
    robot = yourdfpy.URDF.load(str(path), load_meshes=False, build_collision_scene_graph=False)
    assert robot.actuated_joint_names == [f"joint_{j}" for j in range(1, 7)]
    points, rots = [], []
    for q in np.deg2rad(q_deg):
        robot.update_cfg(q)
        points.append(robot.get_transform("tool_point", "base_link")[:3, 3] * 1000.0)
        rots.append(robot.get_transform("flange", "base_link")[:3, :3])
    return np.array(points), np.array(rots)


@pytest.mark.parametrize("convention", ["dh", "mdh"])
def test_urdf_forward_kinematics_match_ours(
    nominal: RobotModel, result: dict[str, Any], convention: str, tmp_path: Path
) -> None:
    model = model_from_result(result, nominal)
    if convention == "mdh":  # the same numbers read as a modified-DH chain: another robot
        model = replace(model, convention="mdh", tool_mm=np.array([15.0, -25.0, 140.0]))
    path = tmp_path / "robot.urdf"
    path.write_text(model_to_urdf(model), encoding="utf-8")
    q = _poses(model, 100, 22)
    points, rots = _urdf_fk(path, q)
    rot, origin = forward_frames(model.dh_internal(), np.deg2rad(q), model.convention)
    ours = tool_position(rot, origin, model.tool_mm)
    worst = float(np.max(np.linalg.norm(points - ours, axis=1)))
    print(f"{convention}: URDF vs ours, worst tool-point difference {worst:.2e} mm")
    assert worst < 1e-6
    np.testing.assert_allclose(rots, rot[:, 6], atol=1e-12)


def test_urdf_limits_and_continuous_joints(nominal: RobotModel) -> None:
    text = model_to_urdf(nominal)
    assert text.count('type="revolute"') == 6 and text.count('type="fixed"') == 2
    assert f'upper="{math.radians(90.0)!r}"' in text  # q2 max 90 deg, in rad
    free = replace(nominal, joint_limits_deg=None)
    assert model_to_urdf(free).count('type="continuous"') == 6


def test_toml_round_trip_predicts_the_same_lengths(
    nominal: RobotModel, result: dict[str, Any]
) -> None:
    text = export_result(result, "toml", nominal)
    assert text.startswith("# Calibrated model of 'hsr-jr680'")
    loaded = parse_model_text(text, "toml")
    assert loaded.name == "hsr-jr680-calibrated"
    assert loaded.joint_limits_deg is not None and nominal.joint_limits_deg is not None
    np.testing.assert_array_equal(loaded.joint_limits_deg, nominal.joint_limits_deg)
    q = _poses(nominal, 200, 23)
    expected = predict_lengths_from_result(result, q)
    # The loaded model as a *nominal* model with zero errors and the result's anchor.
    layout = ParamLayout(("A",))
    theta = np.zeros(layout.size)
    theta[N_KIN:] = [*result["anchor_mm"], result["length_offset_mm"]]
    got = predict_lengths(loaded, theta, np.deg2rad(q), np.zeros(len(q), dtype=int))
    assert np.max(np.abs(got - expected)) < 1e-9
    assert not np.allclose(loaded.dh_table, nominal.dh_table)  # it is the calibrated table


def test_json_export_is_a_model_file(nominal: RobotModel, result: dict[str, Any]) -> None:
    model = model_from_result(result, nominal)
    loaded = parse_model_text(export_model(model, "json"), "json")
    np.testing.assert_array_equal(loaded.dh_table, model.dh_table)
    np.testing.assert_array_equal(loaded.tool_mm, model.tool_mm)
    assert loaded.convention == model.convention


def test_bad_input_is_named(nominal: RobotModel, result: dict[str, Any]) -> None:
    with pytest.raises(ValueError, match="dh"):
        model_from_result({"robot": "x"})
    broken = {**result, "dh": [dict(r) for r in result["dh"]]}
    broken["dh"][1]["a_mm"] = "wide"
    with pytest.raises(ResultError, match=r"dh\[1\]\.a_mm: must be a number, got 'wide'"):
        model_from_result(broken)
    with pytest.raises(ValueError, match="format"):
        export_model(nominal, "step")
