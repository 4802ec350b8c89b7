"""Identification options: one definition, field-named errors, one validate for every caller."""

from __future__ import annotations

import numpy as np
import pytest

from calib.cable import ParamLayout
from calib.dataset import SampleError, SampleSet, make_samples
from calib.identifiability import candidate_mask, max_solved, with_tool
from calib.identify import identify
from calib.methods import REGISTRY
from calib.models import builtin_model
from calib.options import (
    METHODS,
    MIN_TRAINING_SAMPLES,
    IdentifyOptions,
    OptionError,
    default,
    options_from_mapping,
    options_mapping,
    validate,
)
from calib.protocol import paper_split
from calib.robust import WEIGHTS
from calib.synthetic import make_true_cell, random_poses_deg
from daemon.api.schemas import IdentificationRequest

MODEL = builtin_model("hsr-jr680")


def _samples(n: int) -> SampleSet:
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
    validate(samples, options_from_mapping({"fix": ["a2"], "free": ["theta1"]}), model=MODEL)
    with pytest.raises(OptionError, match=r"^free: unknown parameter name\(s\) \['a9'\]"):
        validate(samples, IdentifyOptions(free=("a9",)), model=MODEL)
    few = _samples(30)
    validate(few, IdentifyOptions(test_fraction=0.0), model=MODEL)
    with pytest.raises(SampleError, match="19 training samples"):
        validate(few, IdentifyOptions(test_fraction=0.0), train_rows=range(19), model=MODEL)


def _anchored(n: int, anchors: str) -> SampleSet:
    s = _samples(n)
    return make_samples(s.joints_deg, s.length_mm, [anchors[i % len(anchors)] for i in range(n)])


# (anchors, options, parameters identify solves at most) on the built-in HSR-JR680: 31 in the
# layout of one anchor, less theta1 and d1 (the anchor absorbs them), d3 (parallel to d2) and
# the four joint-6 parameters (the solved tool point absorbs them): 24.
BOUNDS = [
    ("A", {}, 24),
    ("AB", {}, 28),  # 4 more per anchor: P0 and the zero offset
    ("A", {"free": ("theta1",)}, 25),
    ("A", {"fix": ("a2",)}, 23),
]


@pytest.mark.parametrize(("anchors", "values", "n_params"), BOUNDS)
def test_the_bound_is_the_count_identify_solves(
    anchors: str, values: dict[str, object], n_params: int
) -> None:
    layout = ParamLayout(tuple(anchors))
    opts = IdentifyOptions(**values)  # type: ignore[arg-type]
    candidates = candidate_mask(layout, opts.identify_tool, opts.fix)
    assert max_solved(MODEL, layout, candidates, opts.free, rtol=opts.rtol) == n_params


@pytest.mark.parametrize(("anchors", "values", "n_params"), BOUNDS)
def test_too_few_training_rows_for_the_parameters_is_refused_before_the_fit(
    anchors: str, values: dict[str, object], n_params: int
) -> None:
    need = max(n_params + 1, MIN_TRAINING_SAMPLES)
    opts = IdentifyOptions(test_fraction=0.0, **values)  # type: ignore[arg-type]
    validate(_anchored(need, anchors), opts, model=MODEL)  # at the bound: accepted
    with pytest.raises(SampleError) as info:
        validate(_anchored(need - 1, anchors), opts, model=MODEL)
    message = str(info.value)
    assert f"{need - 1} training samples" in message and f"need at least {need}:" in message
    if need == n_params + 1:
        assert f"identify solves {n_params} parameters here" in message
    else:
        assert f"no identification trains on fewer than {MIN_TRAINING_SAMPLES} rows" in message


def test_the_bound_counts_the_rows_the_test_fraction_leaves() -> None:
    # 31 - round(0.2 * 31) = 25 training rows: enough; 30 - 6 = 24: one short.
    validate(_samples(31), IdentifyOptions(), model=MODEL)
    with pytest.raises(SampleError, match=r"^samples: 24 training samples .* need at least 25:"):
        validate(_samples(30), IdentifyOptions(), model=MODEL)


def test_a_fixed_tool_point_on_the_flange_axis_hides_parameters() -> None:
    # The built-in hook point is the flange centre: with the tool point held, alpha6 and
    # theta6 do not move it, nor (on this robot) d5 and theta5: 21 parameters, so the floor
    # of 24 rows applies; a hook point off the axis lets them back in (24).
    layout = ParamLayout(("A",))
    candidates = candidate_mask(layout, False, ())
    assert max_solved(MODEL, layout, candidates, ()) == 21
    off_axis = with_tool(MODEL, (40.0, 0.0, 120.0))
    assert max_solved(off_axis, layout, candidates, ()) == 24
    opts = IdentifyOptions(test_fraction=0.0, identify_tool=False, tool_mm=(40.0, 0.0, 120.0))
    with pytest.raises(SampleError, match="need at least 25: identify solves 24"):
        validate(_samples(24), opts, model=MODEL)


def test_identify_applies_the_bound_before_fitting() -> None:
    cell = make_true_cell(MODEL)
    q = random_poses_deg(cell, 25, np.random.default_rng(3))
    samples = make_samples(q, cell.lengths_mm(q))
    opts = IdentifyOptions(method="lm", test_fraction=0.0, robust="none")
    with pytest.raises(SampleError, match=r"24 training samples .* need at least 25"):
        identify(MODEL, samples.subset(np.arange(24)), opts)
    result = identify(MODEL, samples, opts)  # at the bound: runs
    assert len(result.free_names) <= 24


def test_rest_body_is_built_from_the_options() -> None:
    body = IdentificationRequest()
    for name, value in options_mapping(body.to_options()).items():
        assert value == (list(v) if isinstance(v := default(name), tuple) else v), name
    assert body.to_options(0.05).noise_mm == 0.05  # the [jobs] default when the body has none
    assert IdentificationRequest(noise_mm=0.2).to_options(0.05).noise_mm == 0.2
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


def test_the_api_the_page_and_the_cli_expose_one_list_of_identification_options() -> None:
    """IdentificationRequest's fields are the one list: GET /options/identify serves them to
    the page (with the main ones), and ``cablecal identify`` has an option for each."""
    import inspect

    from daemon.api.option_spec import MAIN_FIELDS, identify_options_spec
    from daemon.cli.calibration import identify_cmd

    body = list(IdentificationRequest.model_fields)
    assert "noise_rank" in body
    served = identify_options_spec()
    assert [f["name"] for f in served["fields"]] == body
    assert served["main_fields"] == list(MAIN_FIELDS) and set(MAIN_FIELDS) <= set(body)
    cli_only = {"data", "robot", "out", "strict"}
    assert set(inspect.signature(identify_cmd).parameters) - cli_only == set(body)
