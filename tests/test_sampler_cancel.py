"""Issue 31 item 1: no wait in the sampler, the drivers or the jobs swallows a cancel, and a
cancelled capture stores nothing.

The race is built, not timed: the capture waits for the indicator's tick, and in one step of
the event loop the window settles, the tick fires and the capture is cancelled. Python 3.11's
``asyncio.wait_for`` returned normally in exactly that case, and the cancelled capture went on
to store its sample (and a task looping on captures ran on past its cancel)."""

from __future__ import annotations

import ast
import asyncio
from dataclasses import dataclass
from pathlib import Path

import pytest
from sampler_fakes import FAST, FakeIndicator, FakeRobot, FakeSink

from daemon.sampler.config import SamplerConfig
from daemon.sampler.core import Sampler
from daemon.sampler.settle import Verdict

pytestmark = pytest.mark.anyio

ROOT = Path(__file__).resolve().parents[1]


@dataclass
class Rig:
    """A sampler whose poll loops do not run (nothing is timed): its settle check answers
    "moving" until ``settled`` is set, then a settled window; ``asked`` is set at each check."""

    sampler: Sampler
    sink: FakeSink
    settled: asyncio.Event
    asked: asyncio.Event

    def settle_and_tick(self) -> None:
        self.settled.set()
        self.sampler._wake()  # as an indicator cycle does: the tick fires and is renewed


def _rig() -> Rig:
    sink = FakeSink()
    sampler = Sampler(FakeIndicator(), FakeRobot(), SamplerConfig(**FAST), sink)  # type: ignore[arg-type]
    rig = Rig(sampler, sink, asyncio.Event(), asyncio.Event())

    def evaluate(now: float, not_before: float) -> Verdict:
        rig.asked.set()
        if rig.settled.is_set():
            return Verdict(None, "settled")
        return Verdict("moving", "the robot moves")

    def store(campaign_id: int, anchor: str, window: object, mode: str) -> dict[str, object]:
        sink.captures.append((campaign_id, None))  # type: ignore[arg-type]
        return {"id": len(sink.captures)}

    sampler._evaluate = evaluate  # type: ignore[method-assign]
    sampler._device_fault = lambda now, not_before: None  # type: ignore[method-assign]
    sampler._store = store  # type: ignore[method-assign,assignment]
    # the poll task "runs" (a future that never ends), so a capture waits for ticks
    sampler._task = asyncio.get_running_loop().create_future()  # type: ignore[assignment]
    return rig


async def test_a_capture_cancelled_as_the_tick_fires_stores_nothing() -> None:
    for _ in range(20):  # the same interleaving every time
        rig = _rig()
        task = asyncio.create_task(rig.sampler.capture(1, anchor="A"))
        await rig.asked.wait()  # checked once, now waiting for the tick
        await asyncio.sleep(0)
        rig.settle_and_tick()  # in one step: settled, tick, cancel
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task
        assert rig.sink.captures == [], "a cancelled capture stored its sample"


async def test_a_capture_loop_stops_at_its_first_cancel() -> None:
    """The issue's loop: a task looping on ``capture`` went on capturing after its cancel."""
    rig = _rig()
    captured = 0

    async def loop() -> None:
        nonlocal captured
        while True:
            rig.asked.clear()
            task = asyncio.create_task(rig.sampler.capture(1, anchor="A"))
            await task
            captured += 1
            rig.settled.clear()

    runner = asyncio.create_task(loop())
    for _ in range(3):  # three captures go through
        await rig.asked.wait()
        await asyncio.sleep(0)
        rig.settle_and_tick()
        while rig.settled.is_set():
            await asyncio.sleep(0)
    await rig.asked.wait()
    await asyncio.sleep(0)
    rig.settle_and_tick()
    runner.cancel()
    with pytest.raises(asyncio.CancelledError):
        await runner
    assert captured == 3
    assert len(rig.sink.captures) == 3


def test_no_asyncio_wait_for_in_package_code() -> None:
    """Every timed wait in the packages is ``asyncio.timeout`` (which never loses a cancel),
    not Python 3.11's ``asyncio.wait_for`` (which can)."""
    found = []
    for pkg in ("daemon", "drivers", "simulator", "calib"):
        for path in sorted((ROOT / pkg).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                if (
                    isinstance(node, ast.Attribute)
                    and node.attr == "wait_for"
                    and isinstance(node.value, ast.Name)
                    and node.value.id == "asyncio"
                ):
                    found.append(f"{path.relative_to(ROOT)}:{node.lineno}")
    assert found == []
