"""The Watlow F4T and ESPEC P-300 drivers against their twins over real loopback sockets:
the Chamber protocol end to end on the world's chamber, and each fault (lost connection,
late answers, refusals, the stuck chamber's alarm) raising its documented typed exception."""

from __future__ import annotations

import subprocess
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import pytest

from common.clock import ScaledClock
from drivers import espec_p300, watlow_f4t
from drivers.errors import (
    ChamberAlarm,
    ChamberSetpointNotReached,
    ConnectionLost,
    InstrumentTimeout,
    SetpointOutOfRange,
)
from drivers.protocols import Chamber, ChamberReadsBackSafe, Reconnectable
from drivers.ramped_chamber import RampedChamber
from drivers.sim.espec_twin import EspecP300Twin
from drivers.sim.watlow_f4t_twin import WatlowF4TTwin
from drivers.sim.world import World
from tests.drivers._chamber_twin_thread import TwinThread
from tests.drivers._fakes import ManualClock

SPEED = 600.0
CONFIG = {"chamber": {"setpoint_low_c": -45.0, "setpoint_high_c": 140.0, "firmware": "2.1"}}


@dataclass
class Family:
    name: str
    twin: Callable[[World], Any]
    factory: Callable[[dict[str, Any]], RampedChamber]


FAMILIES = [
    Family("watlow-f4t", WatlowF4TTwin, watlow_f4t.factory),
    Family("watlow-f4t in F", lambda w: WatlowF4TTwin(w, fahrenheit=True), watlow_f4t.factory),
    Family("espec-p300", EspecP300Twin, espec_p300.factory),
]


@pytest.fixture(params=FAMILIES, ids=lambda f: f.name)
def rig(request: pytest.FixtureRequest) -> Iterator[tuple[TwinThread[Any], RampedChamber]]:
    family: Family = request.param
    with TwinThread(family.twin, CONFIG, speed=SPEED) as tt:
        driver = family.factory({"address": tt.endpoint, "timeout_s": 0.5, "poll_s": 5.0})
        driver.attach_clock(ScaledClock(SPEED))
        try:
            yield tt, driver
        finally:
            driver.close()


def test_driver_is_a_chamber_and_reads_the_world(rig):
    tt, chamber = rig
    assert isinstance(chamber, Chamber)
    assert chamber.setpoint_limits() == pytest.approx((-45.0, 140.0), abs=1e-3)
    truth = tt.call(tt.world.chamber.truth)
    assert chamber.read_temperature() == pytest.approx(truth["air_c"], abs=0.06)
    assert not chamber.is_running()
    assert chamber.identify().model


def test_setpoint_run_wait_stop_and_safe_state_move_the_world(rig):
    tt, chamber = rig
    chamber.set_ramp_rate(0.0)
    chamber.set_setpoint(31.5)
    chamber.run()
    assert chamber.is_running() and tt.world.chamber.running
    assert tt.world.chamber.setpoint_c == pytest.approx(31.5, abs=1e-3)
    assert chamber.read_setpoint() == pytest.approx(31.5, abs=1e-3)
    pv = chamber.wait_setpoint(0.5, 3600.0)
    assert abs(pv - 31.5) <= 0.5
    assert abs(tt.call(tt.world.chamber.truth)["air_c"] - 31.5) < 0.6
    chamber.stop()
    assert not chamber.is_running() and not tt.world.chamber.running
    chamber.set_setpoint(80.0)
    chamber.safe_state(25.0)
    assert tt.world.chamber.running and tt.world.chamber.setpoint_c == pytest.approx(25.0)


def test_driver_ramp_holds_the_twin_below_its_own_maximum_rate(rig):
    tt, chamber = rig
    clock = ManualClock()  # the driver's station clock: polls exactly 5 s apart
    chamber.attach_clock(clock)
    chamber.set_ramp_rate(1.0)  # C/min; the twin's chamber could do 5
    chamber.run()
    start_c = chamber.read_temperature()
    chamber.set_setpoint(35.0)
    for _ in range(24):  # two station minutes, polled as the station does
        clock.sleep_s(5.0)
        chamber.read_temperature()
    assert chamber.read_setpoint() == 35.0  # the target
    ramped = tt.world.chamber.setpoint_c  # what the driver has written so far
    assert ramped == pytest.approx(start_c + 2.0, abs=0.06)


def test_setpoint_beyond_the_limits_is_refused_and_nothing_written(rig):
    tt, chamber = rig
    with pytest.raises(SetpointOutOfRange):
        chamber.set_setpoint(141.0)
    assert tt.world.chamber.setpoint_c == 25.0


def test_controller_refusal_when_its_limits_narrowed(rig):
    tt, chamber = rig
    chamber.setpoint_limits()  # cached: -45..140
    narrow = tt.world.chamber.cfg.model_copy(update={"setpoint_high_c": 60.0})
    tt.call(lambda: setattr(tt.world.chamber, "cfg", narrow))
    with pytest.raises(SetpointOutOfRange, match="refused"):
        chamber.set_setpoint(100.0)
    assert chamber.setpoint_limits()[1] == pytest.approx(60.0, abs=1e-3)  # read again


def test_stuck_chamber_with_its_alarm_raises_chamber_alarm(rig):
    tt, chamber = rig
    chamber.set_setpoint(60.0)
    chamber.run()
    assert chamber.probe() == ""
    tt.stick_chamber(report_fault=True)
    assert "alarm" in chamber.probe()
    with pytest.raises(ChamberAlarm, match="cannot reach 60 C"):
        chamber.watchdog_check()
    with pytest.raises(ChamberAlarm, match="alarm"):
        chamber.wait_setpoint(0.5, 3600.0)


def test_stuck_chamber_without_alarm_times_out(rig):
    tt, chamber = rig
    chamber.set_setpoint(60.0)
    chamber.run()
    tt.stick_chamber(report_fault=False)
    with pytest.raises(ChamberSetpointNotReached) as err:
        chamber.wait_setpoint(0.5, 60.0)
    assert not isinstance(err.value, ChamberAlarm)


def test_drop_is_connection_lost_and_restore_serves_again(rig):
    tt, chamber = rig
    assert chamber.read_temperature() == pytest.approx(25.0, abs=0.1)
    tt.run(tt.twin.drop())
    with pytest.raises(ConnectionLost):
        chamber.read_temperature()
    with pytest.raises(ConnectionLost):  # refused while dropped
        chamber.read_temperature()
    tt.run(tt.twin.restore())
    assert chamber.read_temperature() == pytest.approx(25.0, abs=0.5)


def test_late_answers_are_instrument_timeout_then_recovers(rig):
    tt, chamber = rig
    tt.twin.delay_s = 1.0
    with pytest.raises(InstrumentTimeout):
        chamber.is_running()
    tt.twin.delay_s = 0.0
    assert chamber.is_running() is False  # reconnected, the late reply not taken


def test_twin_endpoint_is_the_drivers_address_form():
    with TwinThread(EspecP300Twin) as espec, TwinThread(WatlowF4TTwin) as f4t:
        for tt, settings in ((espec, espec_p300.Settings), (f4t, watlow_f4t.Settings)):
            host, _, port = tt.endpoint.rpartition(":")
            assert host == "127.0.0.1" and int(port) > 0
            settings.model_validate({"address": tt.endpoint})


@pytest.mark.usefixtures("socat")
def test_espec_driver_over_a_serial_device_path(tmp_path):
    """The P-300's serial port: a pseudo-terminal that socat bridges to the twin's TCP port."""
    with TwinThread(EspecP300Twin, CONFIG, speed=SPEED) as tt:
        link = tmp_path / "ttyP300"
        bridge = subprocess.Popen(
            ["socat", f"pty,link={link},raw,echo=0", f"tcp:{tt.endpoint}"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        )
        try:
            deadline = time.monotonic() + 10
            while not link.exists() and time.monotonic() < deadline:
                time.sleep(0.02)
            chamber = espec_p300.factory({"address": str(link), "timeout_s": 1.0})
            try:
                assert chamber.setpoint_limits() == (-45.0, 140.0)
                chamber.set_setpoint(33.0)
                assert tt.world.chamber.setpoint_c == 33.0
                assert chamber.identify().firmware == "P300 VER 2.1"
            finally:
                chamber.close()
        finally:
            bridge.terminate()
            bridge.wait(5)


def test_check_safe_reads_the_controllers_own_setpoint_back(rig):
    """Issue 25 finding 13: the F4T and P-300 read back their safe state as the F4 does."""
    tt, chamber = rig
    assert isinstance(chamber, ChamberReadsBackSafe)
    chamber.run()
    chamber.set_ramp_rate(0.0)
    chamber.set_setpoint(80.0)
    readback = chamber.check_safe(25.0)
    assert not readback.safe and "setpoint 80 C (safe 25 C)" in readback.detail
    chamber.safe_state(25.0)
    readback = chamber.check_safe(25.0)
    assert readback.safe and "running" in readback.detail, readback
    assert chamber.check_safe(200.0).safe is False  # clamped to the limit, 140 C: not held
    tt.call(lambda: setattr(tt.world.chamber, "setpoint_c", 60.0))  # changed at the panel
    assert chamber.check_safe(25.0).safe is False


def test_reconnect_gets_through_after_a_drop_with_a_longer_timeout(rig):
    tt, chamber = rig
    assert isinstance(chamber, Reconnectable)
    chamber.read_temperature()  # the twin has taken the connection: drop closes it
    tt.run(tt.twin.drop())
    with pytest.raises(ConnectionLost):
        chamber.read_temperature()
    with pytest.raises(ConnectionLost):  # the reconnect itself is refused while dropped
        chamber.reconnect()
    tt.run(tt.twin.restore())
    tt.twin.delay_s = 0.8  # slower than the configured 0.5 s
    chamber.reconnect(timeout_s=3.0)
    assert chamber.read_temperature() == pytest.approx(25.0, abs=0.5)
    tt.twin.delay_s = 0.0
    chamber.safe_state(25.0)
    assert chamber.check_safe(25.0).safe
