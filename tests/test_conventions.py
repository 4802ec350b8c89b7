"""The controller's joint conventions in a model file (issue 34 item 1): parsed with errors
that name the field, round-tripped, inverted exactly; files without them keep their meaning."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from calib.conventions import IDENTITY, JointConvention, convention_from_mapping
from calib.dataset import make_samples
from calib.export import model_from_result, model_to_urdf
from calib.identify import identify
from calib.ik import IKOptions, solve_ik, tool_pose
from calib.kinematics import FloatArray, forward_position
from calib.models import HSR_JR680, ModelError, RobotModel, model_from_mapping
from calib.options import IdentifyOptions
from calib.predict import predict_lengths_from_result
from calib.synthetic import make_true_cell, noisy_lengths, random_poses_deg
from calib.tcp import aligned_position_error_mm


def test_a_model_without_a_controller_table_counts_as_its_table() -> None:
    model = model_from_mapping(HSR_JR680)
    assert model.controller == IDENTITY and model.controller.is_identity
    assert "controller" not in model.to_dict()


def test_directions_and_a_coupling_round_trip_and_invert() -> None:
    data = {
        **HSR_JR680,
        "controller": {
            "maker": "fanuc",
            "direction": [1, 1, -1, -1, -1, -1],
            "couplings": [{"joint": 3, "from": 2, "factor": 1.0}],
        },
    }
    model = model_from_mapping(data)
    conv = model.controller
    assert conv.maker == "fanuc" and conv.couplings == ((2, 1, 1.0),)
    again = model_from_mapping(model.to_dict())
    assert again.controller == conv
    q = np.random.default_rng(1).uniform(-170, 170, (50, 6))
    table = conv.to_table_deg(q)
    assert np.allclose(table[:, 2], -q[:, 2] + q[:, 1])
    assert np.allclose(table[:, 3:], -q[:, 3:])
    assert np.allclose(conv.to_controller_deg(table), q, atol=1e-12)


@pytest.mark.parametrize(
    ("controller", "field"),
    [
        ({"direction": [1, 1, 2, 1, 1, 1]}, "controller.direction[3]"),
        ({"direction": [1, 1]}, "controller.direction"),
        ({"maker": "acme"}, "controller.maker"),
        ({"couplings": [{"joint": 3, "from": 3}]}, "controller.couplings[1].from"),
        ({"couplings": [{"joint": 7, "from": 2}]}, "controller.couplings[1].joint"),
        (
            {"couplings": [{"joint": 3, "from": 2, "factor": 1.0, "x": 1}]},
            "controller.couplings[1]",
        ),
        (
            {
                "couplings": [{"joint": 2, "from": 1, "factor": -1.0}],
                "direction": [1, 1, 1, 1, 1, 1],
            },
            None,
        ),
        ({"speed": 1}, "controller.speed"),
        ({"external_axes": -1}, "controller.external_axes"),
        ({"external_axes": 7}, "controller.external_axes"),
        ({"external_axes": True}, "controller.external_axes"),
        ({"external_axes": 0}, None),
    ],
)
def test_a_bad_controller_table_names_its_field(
    controller: dict[str, object], field: str | None
) -> None:
    data = {**HSR_JR680, "controller": controller}
    if field is None:  # valid
        assert isinstance(model_from_mapping(data).controller, JointConvention)
        return
    with pytest.raises(ModelError) as err:
        model_from_mapping(data)
    assert err.value.field == field, str(err.value)


def test_external_axes_round_trip_and_leave_the_kinematics_alone() -> None:
    model = model_from_mapping({**HSR_JR680, "controller": {"external_axes": 0}})
    assert model.controller.external_axes == 0 and model.controller.is_identity
    assert model.to_dict()["controller"]["external_axes"] == 0
    assert model_from_mapping(model.to_dict()).controller == model.controller
    q = np.array([10.0, -20.0, 30.0, 40.0, 50.0, 60.0])
    assert np.array_equal(model.table_rad(q), model_from_mapping(HSR_JR680).table_rad(q))


# --- the convention applied by the kinematics (one door: RobotModel.table_rad) -------------

#: J3 counted reversed and coupled to J2 (the pendant's J3 is the forearm's angle from the
#: horizontal, as on a Fanuc), J6 reversed: table = M @ controller.
_COUPLED = {"direction": [1, 1, -1, 1, 1, -1], "couplings": [{"joint": 3, "from": 2}]}


def _coupled_twin() -> tuple[RobotModel, RobotModel]:
    """The JR680 as its table counts, and the same arm whose controller counts per _COUPLED
    (no joint limits: the table's limits do not hold in the other counting)."""
    plain = model_from_mapping(HSR_JR680)
    twin = dataclasses.replace(
        plain, controller=convention_from_mapping(_COUPLED), joint_limits_deg=None
    )
    return plain, twin


def test_table_rad_is_deg2rad_bit_for_bit_for_the_identity() -> None:
    plain, twin = _coupled_twin()
    q = np.random.default_rng(3).uniform(-170, 170, (40, 6))
    assert np.array_equal(plain.table_rad(q), np.deg2rad(q))
    assert np.array_equal(plain.controller_deg(np.deg2rad(q)), np.rad2deg(np.deg2rad(q)))
    table = twin.table_rad(q)
    assert np.allclose(np.rad2deg(table[:, 2]), -q[:, 2] + q[:, 1])
    assert np.allclose(twin.controller_deg(table), q, atol=1e-12)


def test_fk_and_ik_take_and_give_the_controllers_angles() -> None:
    plain, twin = _coupled_twin()
    q_table = np.random.default_rng(4).uniform(-60, 60, (25, 6)) + np.array([0, -40, 180, 0, 40, 0])
    q_ctrl = twin.controller.to_controller_deg(q_table)
    assert not np.allclose(q_ctrl, q_table)
    tool = np.array([10.0, 0.0, 80.0])
    pos_p, rot_p = tool_pose(plain, q_table, tool)
    pos_t, rot_t = tool_pose(twin, q_ctrl, tool)
    assert np.allclose(pos_p, pos_t, atol=1e-9) and np.allclose(rot_p, rot_t, atol=1e-12)
    sol = solve_ik(twin, q_ctrl + 3.0, pos_t, rot_t, tool, IKOptions())
    assert sol.converged.all()
    assert np.allclose(sol.joints_deg, q_ctrl, atol=1e-4)  # the controller's branch


def _held_out_tool_error_mm(model: RobotModel, q_ctrl: FloatArray, rng_seed: int) -> float:
    """Identify ``model`` on a true cell (Table XII D1 errors) from 60 controller poses, and
    return the RMS aligned tool-point error [mm] at 40 held-out poses."""
    cell = make_true_cell(model)
    rng = np.random.default_rng(rng_seed)
    train, test = q_ctrl[:60], q_ctrl[60:]
    samples = make_samples(train, noisy_lengths(cell, train, rng, noise_mm=0.02))
    res = identify(model, samples, IdentifyOptions(method="lm", test_fraction=0.0))
    fitted = res.calibrated_model()
    assert fitted.controller == model.controller
    dh, tool = fitted.dh_internal(), fitted.tool_mm
    p_fit = forward_position(dh, fitted.table_rad(test), tool, fitted.convention)
    err = aligned_position_error_mm(p_fit, cell.tool_positions_mm(test))
    return float(np.sqrt(np.mean(err**2)))


def test_a_cell_counted_reversed_and_coupled_identifies_back_its_truth() -> None:
    plain, twin = _coupled_twin()
    q_table = random_poses_deg(make_true_cell(plain), 100, np.random.default_rng(5))
    q_ctrl = twin.controller.to_controller_deg(q_table)
    e_plain = _held_out_tool_error_mm(plain, q_table, 6)
    e_twin = _held_out_tool_error_mm(twin, q_ctrl, 6)
    assert e_plain < 0.2, e_plain  # the fit finds the truth ...
    assert e_twin == pytest.approx(e_plain, abs=1e-4)  # ... counted either way


def test_a_result_keeps_the_convention_and_predicts_with_it() -> None:
    plain, twin = _coupled_twin()
    q_table = random_poses_deg(make_true_cell(plain), 40, np.random.default_rng(8))
    q_ctrl = twin.controller.to_controller_deg(q_table)
    cell = make_true_cell(twin)
    samples = make_samples(q_ctrl, cell.lengths_mm(q_ctrl))
    res = identify(twin, samples, IdentifyOptions(method="lm", test_fraction=0.0))
    result = json.loads(json.dumps(res.to_json()))
    assert result["controller"] == twin.controller.to_dict()
    again = model_from_result(result)
    assert again.controller == twin.controller
    assert np.allclose(predict_lengths_from_result(result, q_ctrl), samples.length_mm, atol=0.05)
    urdf = model_to_urdf(again)
    assert urdf.count('xyz="0 0 -1"') == 2  # J3 and J6 turn the other way
    assert "joint_3 = J3 - 1 * J2" in urdf
    plain_result = identify(plain, make_samples(q_table, samples.length_mm)).to_json()
    assert "controller" not in plain_result


def test_compensate_takes_and_writes_the_controllers_joints() -> None:
    from calib.compensate import CompensateOptions, JointTargets, compensate

    plain, twin = _coupled_twin()
    error = np.zeros((6, 4))
    error[1, 1], error[2, 3], error[4, 3] = 1.5, 0.2, -0.3  # mm, deg, deg
    plain_cal = dataclasses.replace(plain, dh_table=plain.dh_table + error)
    twin_cal = dataclasses.replace(twin, dh_table=twin.dh_table + error)
    q_table = np.random.default_rng(9).uniform(-40, 40, (20, 6)) + np.array([0, -30, 200, 0, 60, 0])
    q_ctrl = twin.controller.to_controller_deg(q_table)
    opts = CompensateOptions(mode="pose", tool_mm=(0.0, 0.0, 100.0))
    want = compensate(plain, plain_cal, JointTargets(q_table), opts)
    got = compensate(twin, twin_cal, JointTargets(q_ctrl), opts)
    assert np.all(want.position_residual_mm < 1e-3) and np.all(got.position_residual_mm < 1e-3)
    assert np.max(np.abs(want.corrected_joints_deg - q_table)) > 0.05  # something to correct
    expected = twin.controller.to_controller_deg(want.corrected_joints_deg)
    assert np.allclose(got.corrected_joints_deg, expected, atol=1e-4)
