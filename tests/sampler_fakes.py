"""Scripted devices and a recording sink for the sampler tests (test_sampler*.py): fake
indicator and robot drivers with seeded noise, lag, drift and injected errors, the helpers
that run a sampler on them, and metric lookups."""

from __future__ import annotations

import asyncio
import time
from collections.abc import AsyncIterator, Callable, Sequence
from contextlib import asynccontextmanager
from typing import Any

import numpy as np
from numpy.typing import NDArray

from daemon import metrics
from daemon.sampler.capture import Capture
from daemon.sampler.config import SamplerConfig
from daemon.sampler.core import Sampler
from drivers import IndicatorReading, JointReading

HOME = (0.0, -30.0, 60.0, 0.0, 45.0, 10.0)
#: Fast settings for the fake devices (they answer every ~5 ms).
FAST: dict[str, Any] = {
    "settle_s": 0.1,
    "stale_s": 0.3,
    "capture_timeout_s": 3.0,
    "error_backoff_s": 0.02,
}


# --------------------------------------------------------------------------- fakes
class FakeIndicator:
    """Scripted indicator: ``length`` plus seeded Gaussian ``noise_mm``; ``error`` is raised
    instead while set; ``lag_s`` back-dates the stamps."""

    def __init__(self, name: str = "ind", length_mm: float = 500.0, noise_mm: float = 0.0) -> None:
        self.name = name
        self.length_mm = length_mm
        self.noise_mm = noise_mm
        self.error: BaseException | None = None
        self.over_range = False
        self.lag_s = 0.0
        self.closed = False
        self._rng = np.random.default_rng(7)

    async def connect(self) -> None:
        pass

    async def read(self) -> IndicatorReading:
        await asyncio.sleep(0.005)
        if self.error is not None:
            raise self.error
        length = self.length_mm + float(self._rng.normal(0.0, self.noise_mm))
        counts = round(length * 100)
        return IndicatorReading(
            length_mm=length,
            counts=counts,
            decimals=2,
            status=1 if self.over_range else 0,
            over_range=self.over_range,
            moving=False,
            t_monotonic_s=time.monotonic() - self.lag_s,
            t_wall=time.time() - self.lag_s,
        )

    async def zero(self) -> None:
        pass

    async def close(self) -> None:
        self.closed = True


class FakeRobot:
    """Scripted robot: at ``joints`` unless moving towards a target (:meth:`move_to`), or
    drifting at ``drift_deg_s`` on joint 1. ``freeze()``: the controller goes on answering
    with fresh stamps but bit-identical joints (the ones of that moment) until ``thaw()``."""

    def __init__(self, name: str = "rob", joints: Sequence[float] = HOME) -> None:
        self.name = name
        self.error: Exception | None = None
        self.lag_s = 0.0
        self.drift_deg_s = 0.0
        self.closed = False
        self._from = np.array(joints, dtype=float)
        self._to = self._from.copy()
        self._t0 = time.monotonic()
        self._move_s = 0.0
        self.frozen: NDArray[np.float64] | None = None

    def freeze(self) -> None:
        self.frozen = self.joints_now()

    def thaw(self) -> None:
        self.frozen = None

    def move_to(self, joints: Sequence[float], move_s: float = 0.15) -> None:
        self._from = self.joints_now()
        self._to = np.array(joints, dtype=float)
        self._t0, self._move_s = time.monotonic(), move_s

    def joints_now(self) -> NDArray[np.float64]:
        t = time.monotonic() - self._t0
        s = 1.0 if self._move_s <= 0 else min(1.0, t / self._move_s)
        q: NDArray[np.float64] = self._from + s * (self._to - self._from)
        q[0] += self.drift_deg_s * t
        return q

    async def connect(self) -> None:
        pass

    async def read_joints(self) -> JointReading:
        await asyncio.sleep(0.003)
        if self.error is not None:
            raise self.error
        q = self.joints_now() if self.frozen is None else self.frozen
        return JointReading(
            (q[0], q[1], q[2], q[3], q[4], q[5]),
            time.monotonic() - self.lag_s,
            time.time() - self.lag_s,
        )

    async def close(self) -> None:
        self.closed = True


class FakeSink:
    """Records what the sampler hands over, like the store would commit it."""

    def __init__(self) -> None:
        self.captures: list[tuple[int, Capture]] = []
        self.rejections: list[tuple[int | None, str, str, str | None]] = []
        #: The pose each refusal was handed over with (6 floats [deg]), or None.
        self.rejection_poses: list[tuple[float, ...] | None] = []
        self.events: list[tuple[str, str | None, str, dict[str, Any] | None]] = []

    def store_capture(self, campaign_id: int, capture: Capture) -> dict[str, Any]:
        self.captures.append((campaign_id, capture))
        return {
            "id": len(self.captures),
            "campaign_id": campaign_id,
            "length_mm": capture.length_mm,
        }

    def record_rejection(
        self,
        campaign_id: int | None,
        reason: str,
        detail: str,
        device: str | None,
        joints_deg: Sequence[float] | None = None,
    ) -> None:
        self.rejections.append((campaign_id, reason, detail, device))
        self.rejection_poses.append(None if joints_deg is None else tuple(joints_deg))

    def record_event(
        self, kind: str, device: str | None, message: str, detail: dict[str, Any] | None = None
    ) -> None:
        self.events.append((kind, device, message, detail))

    def kinds(self, device: str) -> list[str]:
        return [e[0] for e in self.events if e[1] == device]


@asynccontextmanager
async def running(
    indicator: Any, robot: Any, sink: FakeSink, **config: Any
) -> AsyncIterator[Sampler]:
    sampler = Sampler(indicator, robot, SamplerConfig(**{**FAST, **config}), sink)
    await sampler.start()
    try:
        yield sampler
    finally:
        await sampler.stop()


async def wait_until(predicate: Callable[[], bool], timeout_s: float = 10.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError("condition not met in time")
        await asyncio.sleep(0.01)


def length_is(items: Sequence[object], n: int) -> Callable[[], bool]:
    return lambda: len(items) == n


def metric(name: str, **labels: str) -> float:
    return metrics.REGISTRY.get_sample_value(name, labels) or 0.0
