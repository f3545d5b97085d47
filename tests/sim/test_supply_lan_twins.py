"""The Keysight E36300 and Rigol DP800 LAN twins over a real TCP socket (TCPIP SOCKET through
pyvisa + pyvisa-py): a third-party client reads *IDN?, each family's driver drives the world's
supply, and every fault (drop, delay, error reply, shorted part, the serving process killed)
reaches the driver as the documented typed exception."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import pyvisa

from drivers import keysight_e36300, rigol_dp800
from drivers.errors import ConnectionLost, InstrumentTimeout, ScpiError, SupplyCurrentLimit
from drivers.supply import ScpiSupply
from tests.sim._lan_twin import TwinInThread

REPO_ROOT = Path(__file__).resolve().parents[2]
FACTORIES = {"keysight-e36300": keysight_e36300.factory, "rigol-dp800": rigol_dp800.factory}
IDN_START = {
    "keysight-e36300": "Keysight Technologies,E36312A,",
    "rigol-dp800": "RIGOL TECHNOLOGIES,DP832,",
}


@pytest.fixture(params=list(FACTORIES))
def family(request: pytest.FixtureRequest) -> str:
    return str(request.param)


@pytest.fixture
def rig(family: str) -> Iterator[TwinInThread]:
    rig = TwinInThread(family)
    try:
        yield rig
    finally:
        rig.close()


def _driver(family: str, rig: TwinInThread, **settings: object) -> ScpiSupply:
    return FACTORIES[family]({"address": rig.twin.endpoint(), "timeout_s": 1.0, **settings})


def test_pyvisa_with_pyvisa_py_reads_the_twins_idn(family: str, rig: TwinInThread) -> None:
    """Must show: a plain pyvisa client opens the twin's resource string and reads *IDN?."""
    endpoint = rig.twin.endpoint()
    assert endpoint == f"TCPIP::127.0.0.1::{rig.twin.port}::SOCKET"
    manager = pyvisa.ResourceManager("@py")
    instrument = manager.open_resource(endpoint, read_termination="\n", write_termination="\n")
    try:
        idn = instrument.query("*IDN?")
    finally:
        instrument.close()  # not the manager: pyvisa shares one per backend in a process
    assert idn.startswith(IDN_START[family])
    assert len(idn.split(",")) == 4


def test_driver_powers_the_part_through_the_worlds_supply(family: str, rig: TwinInThread) -> None:
    psu = _driver(family, rig, expected_model=IDN_START[family].split(",")[1])
    try:
        psu.reset()
        psu.set_voltage(5.0)
        psu.set_current_limit(0.1)
        assert psu.output_is_on() is False
        psu.output(True)
        assert psu.output_is_on() is True
        truth = rig.truth()
        assert (truth["output"], truth["voltage_set_v"], truth["current_limit_a"]) == (
            True, 5.0, 0.1
        )
        volts, amps = psu.check_current_limit()
        assert volts == pytest.approx(5.0, abs=2e-3)
        assert amps == pytest.approx(truth["amps"], abs=1e-4)
        assert amps > 0.005  # the part draws its current
        psu.check_errors()
        psu.safe_state()
        assert rig.truth()["output"] is False
    finally:
        psu.close()


def test_another_output_leaves_the_parts_supply_alone(family: str) -> None:
    rig = TwinInThread(family, channel=2)
    psu = _driver(family, rig, channel=1)
    part = _driver(family, rig, channel=2)
    try:
        psu.set_voltage(3.3)
        psu.output(True)
        assert psu.measure_voltage() == pytest.approx(3.3, abs=2e-3)
        assert psu.measure_current() == pytest.approx(0.0, abs=1e-4)  # nothing hangs on it
        assert rig.truth()["output"] is False and rig.truth()["voltage_set_v"] == 0.0
        part.set_voltage(5.0)
        part.output(True)
        assert rig.truth()["volts"] == pytest.approx(5.0)
    finally:
        psu.close()
        part.close()
        rig.close()


def test_out_of_range_setting_is_scpi_error_222(family: str, rig: TwinInThread) -> None:
    psu = _driver(family, rig)
    try:
        with pytest.raises(ScpiError, match="-222 Data out of range") as info:
            psu.set_voltage(45.0)  # the simulated supply's maximum is 30 V
        assert info.value.code == -222
        psu.check_errors()  # the queue was drained by the setting
        assert rig.truth()["voltage_set_v"] == 0.0
    finally:
        psu.close()


def test_shorted_part_is_supply_current_limit(family: str, rig: TwinInThread) -> None:
    psu = _driver(family, rig)
    try:
        psu.set_voltage(5.0)
        psu.set_current_limit(0.1)
        psu.output(True)
        psu.check_current_limit()

        def short() -> None:
            part = rig.world.socket(1).part
            assert part is not None
            part.shorted = True

        rig.call(short)  # what the bench's supply_short fault does
        with pytest.raises(SupplyCurrentLimit, match="shorted"):
            psu.check_current_limit()
        assert rig.truth()["mode"] == "CC"
    finally:
        psu.close()


def test_drop_is_connection_lost_and_restore_serves_again(family: str, rig: TwinInThread) -> None:
    psu = _driver(family, rig)
    try:
        psu.identify()
        rig.run(rig.twin.drop())
        t0 = time.monotonic()
        with pytest.raises(ConnectionLost):
            psu.measure_voltage()
        assert time.monotonic() - t0 < 1.5
        with pytest.raises(ConnectionLost):  # refused while dropped
            _driver(family, rig)
    finally:
        psu.close()
    rig.run(rig.twin.restore())
    again = _driver(family, rig)
    try:
        assert again.identify().manufacturer
    finally:
        again.close()


def test_delay_is_a_timeout_and_the_late_reply_is_discarded(family: str, rig: TwinInThread) -> None:
    psu = FACTORIES[family]({"address": rig.twin.endpoint(), "timeout_s": 0.2})
    try:
        rig.twin.delay_s = 0.4
        with pytest.raises(InstrumentTimeout, match="did not answer"):
            psu.output_is_on()
        rig.twin.delay_s = 0.0
        time.sleep(0.4)
        assert psu.measure_voltage() == pytest.approx(0.0, abs=1e-3)  # not the stale "OFF"/0
    finally:
        psu.close()


@pytest.mark.slow
def test_serving_process_killed_is_connection_lost(family: str) -> None:
    proc = subprocess.Popen(
        [sys.executable, "-m", "tests.sim._lan_twin", family],
        cwd=REPO_ROOT,
        stdout=subprocess.PIPE,
        env={**os.environ, "PYTHONPATH": str(REPO_ROOT)},
    )
    try:
        assert proc.stdout is not None
        endpoint = proc.stdout.readline().decode().strip()
        psu = FACTORIES[family]({"address": endpoint, "timeout_s": 1.0})
        try:
            assert psu.identify().serial
            os.kill(proc.pid, signal.SIGKILL)
            proc.wait(5)
            with pytest.raises(ConnectionLost, match="closed the connection|down"):
                psu.measure_voltage()
        finally:
            psu.close()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(5)
