"""Shared helpers for the simulated bench's tests (real sockets and ptys, high speed)."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator

import pytest
from pymodbus.client import ModbusTcpClient

from drivers.sim.launcher import BenchEndpoints, BenchHandle, launch_bench


def u32(hi: int, lo: int) -> int:
    return (hi << 16) | lo


def i32(hi: int, lo: int) -> int:
    v = u32(hi, lo)
    return v - (1 << 32) if v & 0x80000000 else v


def regs32(value: int) -> list[int]:
    v = value & 0xFFFFFFFF
    return [v >> 16, v & 0xFFFF]


def modbus_client(endpoint: str, timeout_s: float = 2.0) -> ModbusTcpClient:
    host, port = BenchEndpoints.host_port(endpoint)
    client = ModbusTcpClient(host, port=port, timeout=timeout_s, retries=0)
    assert client.connect(), f"cannot connect to {endpoint}"
    return client


def wait_until(predicate: Callable[[], bool], timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return
        time.sleep(0.005)
    raise AssertionError(f"timed out after {timeout_s} s wall waiting for {what}")


TWO_PARTS = {
    "parts": [
        {"socket": 1, "serial": "SIM-T001", "bias_dps": 8.6, "scale": 1.0567},
        {"socket": 2, "serial": "SIM-T002"},
    ],
    "table": {"bounce": {"amplitude_deg": 0.02, "frequency_hz": 4.0, "decay_s": 0.15}},
}


@pytest.fixture(scope="session")
def bench() -> Iterator[BenchHandle]:
    """A bench at 100x with two loaded sockets, shared by the tests that leave it sane."""
    with launch_bench(config=TWO_PARTS, speed=100) as handle:
        yield handle
