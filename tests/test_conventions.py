"""The controller's joint conventions in a model file (issue 34 item 1): parsed with errors
that name the field, round-tripped, inverted exactly; files without them keep their meaning."""

from __future__ import annotations

import numpy as np
import pytest

from calib.conventions import IDENTITY, JointConvention
from calib.models import HSR_JR680, ModelError, model_from_mapping


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
