"""The robot library (issue 34 item 2): one plain model file per arm, picked by name; the
``cablecal robots`` listing and ``robots show`` on the command line."""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from calib.models import BUILTIN_MODELS, ModelError, builtin_model, parse_model_text
from calib.robots import (
    INFO_KEYS,
    NAME_PATTERN,
    LibraryError,
    library_info,
    library_model,
    library_names,
    library_text,
)

REPO = Path(__file__).resolve().parents[1]
LIBRARY = REPO / "calib" / "robots" / "library"
NAMES = library_names()


def test_the_library_is_a_folder_of_model_files_and_builtin_models_reads_it() -> None:
    files = sorted(p.stem for p in LIBRARY.iterdir())
    assert files == NAMES and all((LIBRARY / f"{n}.toml").is_file() for n in NAMES)
    assert sorted(BUILTIN_MODELS) == NAMES
    assert {"hsr-jr680", "abb-irb120", "abb-irb6700-200-260"} <= set(NAMES)


@pytest.mark.parametrize("name", NAMES)
def test_every_arm_parses_is_named_as_its_file_and_has_sane_ranges(name: str) -> None:
    assert NAME_PATTERN.fullmatch(name), name
    model = parse_model_text(library_text(name), "toml")
    assert model.name == name
    assert builtin_model(name).to_dict() == model.to_dict()
    limits = model.joint_limits_deg
    assert limits is not None, "a library arm states its joint ranges"
    assert np.all(limits[:, 0] < limits[:, 1])
    assert np.all(np.abs(limits) <= 720.0)
    assert np.all(limits[:, 1] - limits[:, 0] >= 90.0)  # no joint the maker barely moves
    lengths = model.dh_table[:, 1:3]
    assert np.all(np.abs(lengths) < 5000.0) and np.any(np.abs(lengths) > 100.0)
    head = library_text(name).split("\nname =")[0]
    assert head.startswith("# title: "), "the leading comment names the arm"
    assert "\n# maker: " in head
    assert "source" in head.lower() or "paper" in head.lower(), "it names where it comes from"
    assert "[controller]" in library_text(name)


@pytest.mark.parametrize("name", NAMES)
def test_the_info_lines_are_read_from_the_leading_comment(name: str) -> None:
    info = library_info(name)
    assert info.name == name and info.title and info.maker
    for key in ("payload_kg", "reach_mm"):
        line = next((x for x in library_text(name).splitlines() if x.startswith(f"# {key}:")), None)
        assert (getattr(info, key) is None) == (line is None)
    assert set(INFO_KEYS) == {"title", "maker", "payload_kg", "reach_mm"}


def test_abb_reach_is_the_wrist_centre_reach_of_the_table() -> None:
    """ABB's reach is the horizontal distance of the wrist centre from axis 1, stretched:
    a1 + a2 + |(a3, d4)|, within 0.5 %."""
    for name in (n for n in NAMES if n.startswith("abb-")):
        table = library_model(name).dh_table
        a1, a2, a3, d4 = table[0, 1], table[1, 1], table[2, 1], table[3, 2]
        reach = a1 + a2 + float(np.hypot(a3, d4))
        stated = library_info(name).reach_mm
        assert stated is not None and abs(reach - stated) <= 0.005 * stated, (name, reach)


def test_an_unknown_name_names_the_known_ones() -> None:
    with pytest.raises(LibraryError) as err:
        library_text("kuka-kr1000")
    assert "abb-irb120" in str(err.value) and "hsr-jr680" in str(err.value)
    with pytest.raises(ModelError) as merr:
        builtin_model("../hsr-jr680")
    assert merr.value.field == "robot" and "hsr-jr680" in str(merr.value)


def test_the_example_irb120_is_the_library_arm() -> None:
    """examples/abb-irb120.toml has the library's table (joint 6 at 180 deg) and controller."""
    example = parse_model_text((REPO / "examples" / "abb-irb120.toml").read_text(), "toml")
    arm = library_model("abb-irb120")
    assert np.array_equal(example.dh_table, arm.dh_table)
    assert example.controller == arm.controller


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "daemon.cli", "robots", *args],
        cwd=REPO,
        env={**os.environ, "COLUMNS": "80", "NO_COLOR": "1"},
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )


def test_robots_lists_every_arm_whole_at_80_columns() -> None:
    proc = _cli()
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    assert max(len(line) for line in lines) <= 80
    for name in NAMES:
        row = next(line for line in lines if line.split() and line.split()[0] == name)
        info = library_info(name)
        assert info.title is not None and info.title in row
        if info.reach_mm is not None:
            assert f"{info.reach_mm:g}" in row.split()


def test_robots_show_prints_the_model_file_as_robot_takes_it(tmp_path: Path) -> None:
    for name in ("abb-irb120", "hsr-jr680"):
        proc = _cli("show", name)
        assert proc.returncode == 0, proc.stderr
        assert proc.stdout == library_text(name)
        path = tmp_path / f"{name}.toml"
        path.write_text(proc.stdout)
        again = parse_model_text(path.read_text(), "toml")
        assert again.to_dict() == library_model(name).to_dict()


def test_robots_show_an_unknown_name_exits_2_naming_the_known_ones() -> None:
    proc = _cli("show", "nosuch-arm")
    assert proc.returncode == 2
    assert proc.stdout == ""
    assert "nosuch-arm" in proc.stderr and "abb-irb140" in proc.stderr


def test_the_example_jr680_is_the_library_arm() -> None:
    example = parse_model_text((REPO / "examples" / "hsr-jr680.toml").read_text(), "toml")
    assert example.to_dict() == library_model("hsr-jr680").to_dict()


# --- the ABB arms against what the world writes of them (bench/robots_check.py) -------------


def test_abb_arms_give_the_robtargets_their_controllers_wrote() -> None:
    from bench.robots_check import pair_checks

    checks = pair_checks()
    assert {c.arm for c in checks} >= {n for n in NAMES if n.startswith("abb-")} - {
        "abb-irb6700-200-260"
    }
    for c in checks:
        assert c.position_error_mm <= 0.01, c
        assert c.rotation_error_deg <= 1e-4, c


def test_the_previous_irb120_example_was_turned_180_deg_about_joint_6() -> None:
    from bench.robots_check import old_irb120_check

    old = old_irb120_check()
    assert old.position_error_mm <= 0.01  # tool0's origin lies on axis 6 ...
    assert old.rotation_error_deg == pytest.approx(180.0, abs=1e-3)  # ... its frame did not


def test_abb_chains_are_ros_industrials_and_a_reversed_axis_would_show() -> None:
    from bench.robots_check import chain_checks
    from calib.conventions import JointConvention

    for c in chain_checks(poses=60):
        assert c.max_position_mm <= 1e-6 and c.max_rotation_deg <= 1e-6, c
    arm = library_model("abb-irb2600-20-165")
    for j in range(6):
        direction = [1] * 6
        direction[j] = -1
        flipped = dataclasses.replace(arm, controller=JointConvention("abb", tuple(direction)))
        (bad,) = [
            c for c in chain_checks(poses=60, model_of={arm.name: flipped}) if c.arm == arm.name
        ]
        assert bad.max_rotation_deg > 10.0, (j, bad)


def test_the_irb120_olp_pair_holds_every_axis_direction() -> None:
    """The OLP pair has every joint away from zero: reversing any one axis misses it."""
    from bench.robots_check import pair_checks
    from calib.conventions import JointConvention

    arm = library_model("abb-irb120")
    (ok,) = [c for c in pair_checks() if c.tag == "irb120_olp"]
    assert ok.position_error_mm <= 0.001 and ok.rotation_error_deg <= 1e-3
    for j in range(6):
        direction = [1] * 6
        direction[j] = -1
        flipped = dataclasses.replace(arm, controller=JointConvention("abb", tuple(direction)))
        (bad,) = [c for c in pair_checks({arm.name: flipped}) if c.tag == "irb120_olp"]
        assert bad.position_error_mm > 1.0 or bad.rotation_error_deg > 1.0, (j, bad)
