"""Identification options: one definition, field-named errors, one validate for every caller."""

from __future__ import annotations

import numpy as np
import pytest

from calib.dataset import SampleError, make_samples
from calib.methods import REGISTRY
from calib.options import (
    METHODS,
    MIN_TRAINING_SAMPLES,
    IdentifyOptions,
    OptionError,
    default,
    options_from_mapping,
    validate,
)
from calib.protocol import paper_split
from calib.robust import WEIGHTS
from daemon.api.schemas import IdentificationRequest


def _samples(n: int):
    rng = np.random.default_rng(0)
    return make_samples(rng.uniform(-30, 30, (n, 6)), rng.uniform(500, 1500, n))


@pytest.mark.parametrize(
    ("values", "field"),
    [
        ({"method": "magic"}, "method"),
        ({"robust": "l2"}, "robust"),
        ({"holdout": "sideways"}, "holdout"),
        ({"test_fraction": 1.0}, "test_fraction"),
        ({"prior_mm": 0.0}, "prior_mm"),
        ({"bogus": 1}, "bogus"),
    ],
)
def test_bad_option_names_its_field(values: dict[str, object], field: str) -> None:
    with pytest.raises(OptionError, match=f"^{field}: ") as info:
        options_from_mapping(values)
    assert info.value.field == field


def test_validate_checks_names_against_the_layout_and_the_training_rows() -> None:
    samples = _samples(40)
    validate(samples, options_from_mapping({"fix": ["a2"], "free": ["theta1"]}))
    with pytest.raises(OptionError, match=r"^free: unknown parameter name\(s\) \['a9'\]"):
        validate(samples, IdentifyOptions(free=("a9",)))
    few = _samples(MIN_TRAINING_SAMPLES)
    validate(few, IdentifyOptions(test_fraction=0.0))
    with pytest.raises(SampleError, match=f"{MIN_TRAINING_SAMPLES - 5} training samples"):
        validate(
            few, IdentifyOptions(test_fraction=0.0), train_rows=range(MIN_TRAINING_SAMPLES - 5)
        )


def test_rest_body_is_built_from_the_options() -> None:
    body = IdentificationRequest()
    for name, value in body.to_options().items():
        assert value == default(name), name
    schema = IdentificationRequest.model_json_schema()["properties"]
    assert schema["method"]["enum"] == list(METHODS)
    assert schema["test_fraction"]["exclusiveMaximum"] == 1.0


def test_every_method_is_registered_and_every_robust_mode_has_a_weight() -> None:
    assert tuple(REGISTRY) == METHODS
    u = np.array([0.0, 1.0, 10.0])
    for mode, fn in WEIGHTS.items():
        w = fn(u, 1.345)
        assert w.shape == u.shape and w[0] == 1.0, mode
        # A 10-sigma residual is down-weighted by every mode but "none".
        assert (w[-1] == 1.0) if mode == "none" else (0.0 <= w[-1] < 1.0), mode


def test_paper_split_is_disjoint_and_seeded() -> None:
    train, test = paper_split(2017, 3)
    assert train.size == 100 and test.size == 20 and not set(train) & set(test)
    again = paper_split(2017, 3)
    assert np.array_equal(train, again[0]) and np.array_equal(test, again[1])
