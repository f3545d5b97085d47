"""A fixture socket the run does not test, left streaming by a crashed station, is stopped at
the next start too (every fixture stream of the station, scanned or not)."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from common.clock import ScaledClock
from drivers.part_link import SerialPartLink
from drivers.scpi import open_serial
from drivers.sim.launcher import launch_bench
from procedures.runtime.record import Verdict
from station.endpoints import Endpoints
from station.station_file import load_settings
from station.uut import UutRunner

pytestmark = pytest.mark.slow
ROOT = Path(__file__).resolve().parents[2]
SHORT = ROOT / "tests/procedures/data/short.yaml"


def test_an_unscanned_socket_left_streaming_is_stopped(tmp_path: Path) -> None:
    parts = [{"socket": 1, "serial": "SIM-0701"}, {"socket": 2, "serial": "SIM-0702"}]
    with launch_bench(config={"parts": parts}, sockets=2, lockstep=True) as bench:
        e = bench.endpoints
        supply = open_serial(e.supply)  # the crashed station's last acts: power and START
        supply.write(b"VOLT 5.0\nOUTP ON\n")
        supply.flush()
        time.sleep(0.3)
        link = SerialPartLink.open(e.duts[2], ScaledClock(1.0))
        link.command("START")
        link.close()
        supply.close()
        assert bench.control.truth()["sockets"]["2"]["stream_enabled"] is True
        runner = UutRunner(load_settings(), procedure_path=SHORT, out=tmp_path,
                           endpoints=Endpoints.of_bench(e), certificate=False)
        result = runner.run({1: "SIM-0701"})  # socket 2 holds a part nobody scanned
        truth = bench.control.truth()
    assert result.verdicts[1] is Verdict.ERROR and "not scanned" in result.reasons[1]
    assert truth["sockets"]["2"]["stream_enabled"] is False
