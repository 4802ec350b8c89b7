"""Fixtures shared by the tests.

``sim``: the emulated cell (:class:`simulator.runner.SimulatorThread`) on free ports, stopped
after the test. A module or test configures it with the ``emulated_cell`` marker, whose keyword
arguments are the cell's config sections (merged by :func:`helpers.sim_config`) plus
``hold=True`` to hold the robot still (the indicator's value then stays put), e.g.::

    pytestmark = pytest.mark.emulated_cell(hold=True, indicator={"baud": 115200})
"""

from __future__ import annotations

from collections.abc import Iterator

from daemon.process.blas import single_threaded_blas

single_threaded_blas()  # as the cablecal command does, before the tests import numpy

import pytest  # noqa: E402
from helpers import start_emulated_cell  # noqa: E402

from simulator.runner import SimulatorThread  # noqa: E402


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line(
        "markers",
        "emulated_cell(hold=False, **sections): configuration of the `sim` fixture's cell",
    )


@pytest.fixture
def sim(request: pytest.FixtureRequest) -> Iterator[SimulatorThread]:
    """The emulated cell in a thread, as the ``emulated_cell`` marker configures it."""
    marker = request.node.get_closest_marker("emulated_cell")
    s = start_emulated_cell(**(marker.kwargs if marker is not None else {}))
    try:
        yield s
    finally:
        s.stop()
