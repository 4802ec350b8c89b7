"""Independent Modbus masters read the emulated indicator: minimalmodbus (pure Python RTU
master) always, mbpoll (libmodbus) when installed. They must get the same length as our
driver and as the cell's truth."""

from __future__ import annotations

import asyncio
import re
import shutil
import subprocess

import minimalmodbus
import pytest

from drivers import IndicatorConfig, ModbusIndicator
from simulator.runner import SimulatorThread

# hold: the display value stays put (noise drawn once)
pytestmark = pytest.mark.emulated_cell(
    hold=True, indicator={"baud": 19200, "noise_mm": 0.05, "tcp": "mbap"}
)


def _driver_counts(port: str) -> int:
    async def read() -> int:
        ind = ModbusIndicator(IndicatorConfig(port=port, baud=19200))
        try:
            return (await ind.read()).counts
        finally:
            await ind.close()

    return asyncio.run(read())


def test_minimalmodbus_reads_the_same_length(sim: SimulatorThread) -> None:
    port = str(sim.ready["indicator_port"])
    inst = minimalmodbus.Instrument(port, 1)
    inst.serial.baudrate = 19200
    inst.serial.timeout = 0.5
    try:
        counts = inst.read_long(0, functioncode=3, signed=True)  # ABCD = minimalmodbus default
        decimals = inst.read_register(2)
        block = inst.read_registers(0, 8)
    finally:
        inst.serial.close()
    true = sim.control("state")["true_length_mm"]
    assert decimals == 2
    assert abs(counts / 100 - true) < 5 * 0.05 + 0.005
    assert (block[0] << 16 | block[1]) == counts
    assert block[5] << 16 | block[6] == 400  # magnification 0.400 for two decimals
    assert _driver_counts(port) == counts


def test_minimalmodbus_zero_command(sim: SimulatorThread) -> None:
    port = str(sim.ready["indicator_port"])
    inst = minimalmodbus.Instrument(port, 1)
    inst.serial.baudrate = 19200
    inst.serial.timeout = 0.5
    try:
        inst.write_register(0x10, 1, functioncode=6)
        counts = inst.read_long(0, signed=True)
        with pytest.raises(minimalmodbus.IllegalRequestError):
            inst.read_registers(0x200, 2)  # outside the map: exception 02
    finally:
        inst.serial.close()
    assert abs(counts) <= 25  # noise only: 5 sigma at 0.01 mm per count


MBPOLL = shutil.which("mbpoll")


def _mbpoll_values(args: list[str]) -> list[int]:
    out = subprocess.run(
        [str(MBPOLL), *args], capture_output=True, text=True, timeout=20, check=True
    ).stdout
    return [int(v) for v in re.findall(r"^\[\d+\]:\s+(-?\d+)", out, re.M)]


@pytest.mark.skipif(MBPOLL is None, reason="mbpoll not installed (apt-get install mbpoll)")
def test_mbpoll_rtu_and_tcp_read_the_same_length(sim: SimulatorThread) -> None:
    port = str(sim.ready["indicator_port"])
    rtu = _mbpoll_values(
        [
            "-m",
            "rtu",
            "-b",
            "19200",
            "-P",
            "none",
            "-a",
            "1",
            "-0",
            "-r",
            "0",
            "-c",
            "1",
            "-t",
            "4:int",
            "-B",
            "-1",
            "-o",
            "1",
            port,
        ]
    )
    host, tcp_port = str(sim.ready["indicator_tcp"]).rsplit(":", 1)
    tcp = _mbpoll_values(
        [
            "-m",
            "tcp",
            "-p",
            tcp_port,
            "-a",
            "1",
            "-0",
            "-r",
            "0",
            "-c",
            "1",
            "-t",
            "4:int",
            "-B",
            "-1",
            "-o",
            "1",
            host,
        ]
    )
    assert len(rtu) == 1 and rtu == tcp
    assert _driver_counts(port) == rtu[0]
    true = sim.control("state")["true_length_mm"]
    assert abs(rtu[0] / 100 - true) < 5 * 0.05 + 0.005
