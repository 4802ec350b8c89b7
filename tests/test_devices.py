"""Per-device book-keeping without a poll loop: states, error episodes and their events,
faults after stale_s, the manual robot's no-data state, and the status entry."""

from __future__ import annotations

from typing import Any

from daemon.sampler.devices import Device
from drivers import IndicatorCRCError, IndicatorLinkDown, RobotNoData


class Events:
    def __init__(self) -> None:
        self.seen: list[tuple[str, str | None, str, dict[str, Any] | None]] = []

    def __call__(
        self, kind: str, device: str | None, message: str, detail: dict[str, Any] | None
    ) -> None:
        self.seen.append((kind, device, message, detail))

    def kinds(self) -> list[str]:
        return [e[0] for e in self.seen]


def test_an_error_episode_records_one_event_and_a_reconnect() -> None:
    events = Events()
    dev = Device("ind-unit", "indicator", object(), events)
    assert dev.state == "unknown" and dev.fault(0.0, 0.5) is None
    dev.good(1.0, 500.0, False, 1.0, 1.7e9)
    dev.failed(1.1, IndicatorLinkDown("ind-unit", "cannot open /dev/ttyUSB0", ["tx 01 03"]))
    dev.failed(1.2, IndicatorCRCError("ind-unit", "CRC mismatch", ["rx 01 03 ff"]))
    assert events.kinds() == ["link_down"] and dev.episode == 1
    assert events.seen[0][3] == {"error": "IndicatorLinkDown", "frames_hex": ["tx 01 03"]}
    assert dev.errors == {"IndicatorLinkDown": 1, "IndicatorCRCError": 1}
    assert dev.error_text() == "IndicatorCRCError: CRC mismatch"
    # a failing device is a fault only once its last good reading is older than stale_s
    assert dev.fault(1.4, 0.5) is None
    fault = dev.fault(1.6, 0.5)
    assert fault is not None and fault.reason == "indicator_error" and fault.device == "ind-unit"
    assert "CRC mismatch" in fault.detail and fault.http_status == 503
    dev.good(2.0, 501.0, False, 2.0, 1.7e9 + 1)
    assert events.kinds() == ["link_down", "link_up"] and dev.state == "ok"
    assert events.seen[1][3] == {"last_error": "IndicatorCRCError: CRC mismatch"}
    assert dev.fault(10.0, 0.5) is None  # not in error: stale readings are the settle check's


def test_manual_robot_without_angles_is_waiting_not_failing() -> None:
    events = Events()
    dev = Device("manual", "robot", object(), events)
    dev.waiting(1.0, RobotNoData("manual", "no joint angles submitted"))
    dev.waiting(1.1, RobotNoData("manual", "no joint angles submitted"))
    assert dev.state == "unknown" and dev.no_data == "no joint angles submitted"
    assert dev.episode == 1 and dev.t_state_poll == 1.1 and not events.seen
    assert dev.fault(100.0, 0.5) is None and dev.polls == 0


def test_status_reports_reading_error_and_rate() -> None:
    dev = Device("rob-unit", "robot", 3.0, Events())  # driver class: float
    dev.t_started = 0.0
    for k in range(10):
        dev.good(k * 0.1, (1.0, 2.0, 3.0, 4.0, 5.0, 6.0), False, k * 0.1, 1.7e9 + k * 0.1)
    status = dev.status(now=1.0)
    assert status["driver"] == "float" and status["connected"] and status["polls"] == 10
    assert status["last_reading"]["value"] == [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]
    assert abs(status["last_reading"]["age_s"] - 0.1) < 1e-9
    assert status["poll_rate_hz"] == 10.0 and status["last_error"] is None
    dev.prune(7.0)  # stamps older than the 5 s rate window go
    assert dev.rate_hz(7.0) == 0.0
