"""Issue 33 item 4: the identification options are made and checked once per request, and
each step of identify reads only its group of them."""

from __future__ import annotations

import ast
from dataclasses import fields
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import calib.options
import calib.split
from calib.dataset import make_samples
from calib.identify import identify, identify_checked
from calib.models import builtin_model
from calib.options import (
    GROUPS,
    IdentifyOptions,
    PriorOptions,
    RobustOptions,
    SolverSettings,
    options_from_mapping,
    options_mapping,
    part,
    with_part,
)
from calib.split import check
from calib.synthetic import make_true_cell, noisy_lengths, random_poses_deg

ROOT = Path(__file__).resolve().parents[1]
MODEL = builtin_model("hsr-jr680")


def _samples(n: int) -> Any:
    cell = make_true_cell(MODEL)
    rng = np.random.default_rng(5)
    q = random_poses_deg(cell, n, rng)
    return make_samples(q, noisy_lengths(cell, q, rng))


def test_checked_options_run_without_a_second_check(monkeypatch: pytest.MonkeyPatch) -> None:
    samples = _samples(60)
    opts = IdentifyOptions(method="lm", seed=2)
    whole = identify(MODEL, samples, opts)
    calls: list[object] = []
    real = calib.split.validate
    monkeypatch.setattr(calib.split, "validate", lambda *a, **k: calls.append(a) or real(*a, **k))
    checked = check(MODEL, samples, opts)
    assert len(calls) == 1
    made: list[object] = []
    post_init = IdentifyOptions.__post_init__
    monkeypatch.setattr(IdentifyOptions, "__post_init__", lambda s: made.append(s) or post_init(s))
    again = identify_checked(MODEL, samples, checked)
    assert len(calls) == 1  # the worker's side checks nothing again
    # ... and makes no options of its own beyond the prior's fold options (none here: the
    # default prior weight is estimated, not cv)
    assert made == []
    assert np.array_equal(again.theta, whole.theta)
    assert np.array_equal(again.train_rows, checked.train_rows)


def test_the_groups_hold_every_option_they_name_and_round_trip() -> None:
    opts = options_from_mapping({"prior_mm": 3.0, "robust": "huber", "ukf_epochs": 4})
    for group in GROUPS:
        values = part(opts, group)
        for f in fields(group):
            assert getattr(values, f.name) == getattr(opts, f.name), (group, f.name)
        assert with_part(IdentifyOptions(), values) == replace_all(IdentifyOptions(), values)
    assert options_from_mapping(options_mapping(opts)) == opts
    scaled = with_part(opts, PriorOptions(True, 6.0, 0.4, None, "fixed", 0.3))
    assert (scaled.prior_mm, scaled.robust, scaled.ukf_epochs) == (6.0, "huber", 4)


def replace_all(options: IdentifyOptions, values: Any) -> IdentifyOptions:
    kw = {f.name: getattr(values, f.name) for f in fields(values)}
    return options_from_mapping({**options_mapping(options), **kw})


@pytest.mark.parametrize(
    ("module", "group"),
    [
        ("calib/prior.py", PriorOptions),
        ("calib/robust.py", RobustOptions),
        ("calib/methods.py", SolverSettings),
    ],
)
def test_a_step_reads_only_its_group(module: str, group: type) -> None:
    """The module names no other options type, and reads no option outside its group."""
    source = (ROOT / module).read_text(encoding="utf-8")
    tree = ast.parse(source)
    names = {n.id for n in ast.walk(tree) if isinstance(n, ast.Name)}
    names |= {a.name for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) for a in n.names}
    others = {g.__name__ for g in GROUPS if g is not group} | {"IdentifyOptions"}
    assert names & others == set(), module
    own = {f.name for f in fields(group)}
    options = {f.name for f in fields(IdentifyOptions)} - own
    read = {
        n.attr
        for n in ast.walk(tree)
        if isinstance(n, ast.Attribute)
        and isinstance(n.value, ast.Name)
        and n.value.id in ("opts", "options", "used", "prior", "settings")
    }
    assert read & options == set(), (module, read & options)


def test_validate_leaves_the_bounds_to_the_options() -> None:
    """The bounds are checked when options are made (one place); validate checks only what
    needs the samples."""
    with pytest.raises(calib.options.OptionError, match=r"^prior_mm: "):
        IdentifyOptions(prior_mm=-1.0)
    src = (ROOT / "calib/options.py").read_text(encoding="utf-8")
    body = src[src.index("def validate(") : src.index("def check_anchor_rows(")]
    assert ".check(" not in body
