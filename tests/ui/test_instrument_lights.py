"""The instrument lights use each configured driver's own probe, over the bench's sockets."""

from __future__ import annotations

import time
from collections.abc import Callable

from drivers.sim.launcher import launch_bench
from station.endpoints import Endpoints
from station.station_file import load_settings
from station.ui.instruments import InstrumentLight
from station.ui.runner_adapter import EngineRunner


def _by_name(lights: list[InstrumentLight]) -> dict[str, InstrumentLight]:
    return {light.name: light for light in lights}


def _until(check: Callable[[], dict[str, InstrumentLight]], name: str,
           ok: Callable[[InstrumentLight], bool]) -> InstrumentLight:
    deadline = time.monotonic() + 10
    while True:
        light = check()[name]
        if ok(light) or time.monotonic() > deadline:
            return light
        time.sleep(0.1)


def test_lights_follow_each_drivers_probe() -> None:
    with launch_bench(config={"parts": [{"socket": 1, "serial": "SIM-0001"}]}, speed=100) as b:
        runner = EngineRunner(load_settings(), endpoints=Endpoints.of_bench(b.endpoints))

        def lights() -> dict[str, InstrumentLight]:
            return _by_name(runner.instruments())

        now = lights()
        assert set(now) == {"rate table", "chamber", "supply", "fixture 1"}
        assert all(x.connected and not x.faulted for x in now.values()), now
        # the table's own probe reads its status: an open interlock is a fault light
        b.control.fault("interlock_open")
        table = _until(lights, "rate table", lambda x: x.faulted)
        assert table.connected and table.faulted and table.detail == "interlock open"
        # a chamber that stops answering is not connected (its driver cannot open it)
        b.control.fault("modbus_drop", target="chamber")
        chamber = _until(lights, "chamber", lambda x: not x.connected)
        assert not chamber.connected and "no answer at" in chamber.detail
        assert chamber.detail.count(b.endpoints.chamber) >= 1
        b.control.clear_faults()
        assert _until(lights, "chamber", lambda x: x.connected).connected
