"""The `scpi` supply family against the bench's pty twin through pyvisa's ASRL resource (the
way station runs reach it): the world's supply, -222, the supply_short fault, and the bench
process killed under the driver (the pty's other side gone: ConnectionLost, never termios.error
or pyserial's SerialException)."""

from __future__ import annotations

import os
import signal

import pytest

from drivers import supply
from drivers.errors import ConnectionLost, ScpiError, SupplyCurrentLimit
from drivers.sim.launcher import launch_bench

ONE_PART = {"parts": [{"socket": 1, "serial": "SIM-P001"}]}


@pytest.mark.slow
def test_scpi_family_over_the_pty_twin_and_its_faults() -> None:
    with launch_bench(config=ONE_PART, speed=100) as bench:
        path = bench.endpoints.supply
        # today's station.yaml form (a device path and a baud) and the VISA form both open it
        psu = supply.factory({"address": path, "baud": 115200, "timeout_s": 1.0})
        visa = supply.factory({"address": f"ASRL{path}::INSTR", "timeout_s": 1.0})
        try:
            assert visa.identify() == psu.identify()
            visa.close()
            psu.reset()
            psu.set_voltage(5.0)
            psu.set_current_limit(0.1)
            psu.output(True)
            volts, amps = psu.check_current_limit()
            truth = bench.control.truth()["supply"]
            assert (truth["output"], truth["voltage_set_v"]) == (True, 5.0)
            assert volts == pytest.approx(5.0, abs=2e-3) and amps > 0.005
            with pytest.raises(ScpiError, match="-222") as info:
                psu.set_voltage(45.0)
            assert info.value.code == -222
            bench.control.fault("supply_short", socket=1)
            with pytest.raises(SupplyCurrentLimit, match="shorted"):
                psu.check_current_limit()
            os.kill(bench.process.pid, signal.SIGKILL)
            bench.process.wait(10)
            with pytest.raises(ConnectionLost, match="DC supply"):
                psu.measure_voltage()
            with pytest.raises(ConnectionLost):
                psu.safe_state()
        finally:
            psu.close()
            visa.close()
