"""ESPEC P-300 driver against a scripted port: the exact command lines on the wire, the reply
parsing, NA: refusals mapped to typed exceptions, alarms and the driver-side ramp."""

from __future__ import annotations

import pydantic
import pytest

from drivers import espec_p300
from drivers.errors import (
    ChamberAlarm,
    ChamberRefused,
    ConnectionLost,
    InstrumentTimeout,
    ProtocolError,
    SetpointOutOfRange,
)
from drivers.espec_p300 import EspecP300, link_over
from tests.drivers._fakes import ManualClock
from tests.drivers.expected_protocol import SerialPeer, finish

TEMP = (b"TEMP?\r\n", b"24.8,25.0,150.0,-70.0\r\n")  # pv, sp, upper, lower


def ok(command: bytes) -> tuple[bytes, bytes]:
    return command + b"\r\n", b"OK:" + command + b"\r\n"


def make(script, clock=None, **kw):
    port = SerialPeer(script)
    return port, EspecP300(link_over(port, timeout_s=0.05), clock or ManualClock(), **kw)


def test_identify_uses_rom_and_type():
    port, chamber = make(
        [(b"ROM?\r\n", b"P300 VER 1.20\r\n"), (b"TYPE?\r\n", b"T,P300,150\r\n")], serial="E-12"
    )
    ident = chamber.identify()
    assert ident == espec_p300.InstrumentIdentity("ESPEC", "P300", "E-12", "P300 VER 1.20")
    finish(port, chamber)


def test_temp_query_gives_pv_setpoint_and_limits():
    port, chamber = make([TEMP, TEMP, TEMP])
    assert chamber.setpoint_limits() == (-70.0, 150.0)
    assert chamber.read_temperature() == 24.8
    assert chamber.read_setpoint() == 25.0
    assert chamber.setpoint_limits() == (-70.0, 150.0)  # read once
    finish(port, chamber)


def test_setpoint_is_sent_in_tenths():
    port, chamber = make([TEMP, ok(b"TEMP, S-12.5"), ok(b"TEMP, S85.1")])
    chamber.set_setpoint(-12.5)
    chamber.set_setpoint(85.1)
    finish(port, chamber)


def test_setpoint_outside_limits_is_refused_before_sending():
    port, chamber = make([TEMP])
    with pytest.raises(SetpointOutOfRange, match=r"\[-70, 150\]"):
        chamber.set_setpoint(151.0)
    finish(port, chamber)


@pytest.mark.parametrize(
    ("reason", "error"),
    [
        (b"DATA OUT OF RANGE", SetpointOutOfRange),
        (b"PROTECT ON", ChamberRefused),
        (b"CHB NOT READY", ChamberRefused),
        (b"CMD ERR", ProtocolError),
        (b"PARA ERR", ProtocolError),
        (b"SOMETHING NEW", ProtocolError),
    ],
)
def test_na_replies_raise_their_typed_exception(reason, error):
    port, chamber = make([TEMP, (b"TEMP, S30.0\r\n", b"NA:" + reason + b"\r\n")])
    with pytest.raises(error, match=reason.decode()):
        chamber.set_setpoint(30.0)
    finish(port, chamber)


def test_setting_answered_without_ok_is_a_protocol_error():
    port, chamber = make([(b"MODE?\r\n", b"STANDBY\r\n"), (b"MODE, CONSTANT\r\n", b"?\r\n")])
    with pytest.raises(ProtocolError, match="OK:"):
        chamber.run()
    finish(port, chamber)


def test_run_powers_on_from_off_and_sets_constant_from_standby():
    port, chamber = make([
        (b"MODE?\r\n", b"OFF\r\n"),
        ok(b"POWER,ON"),
        (b"MODE?\r\n", b"CONSTANT\r\n"),
        (b"MODE?\r\n", b"STANDBY\r\n"),
        ok(b"MODE, CONSTANT"),
        (b"MODE?\r\n", b"CONSTANT\r\n"),
        ok(b"MODE, STANDBY"),
        (b"MODE?\r\n", b"STANDBY\r\n"),
        (b"MODE?\r\n", b"RUN\r\n"),
    ])
    chamber.run()
    chamber.run()
    chamber.stop()
    assert not chamber.is_running()
    assert chamber.is_running()  # a program running counts as control on
    finish(port, chamber)


def test_wait_setpoint_raises_chamber_alarm_with_the_codes():
    port, chamber = make([
        TEMP,
        (b"MODE?\r\n", b"CONSTANT\r\n"),
        (b"TEMP?\r\n", b"12.0,25.0,150.0,-70.0\r\n"),
        (b"MON?\r\n", b"12.0,,CONSTANT,1\r\n"),
        (b"ALARM?\r\n", b"1,17\r\n"),
    ])
    with pytest.raises(ChamberAlarm, match="alarm code 17"):
        chamber.wait_setpoint(0.5, 600.0)
    finish(port, chamber)


def test_wait_setpoint_returns_in_band_without_alarm_check():
    port, chamber = make([TEMP, (b"MODE?\r\n", b"CONSTANT\r\n"), TEMP])
    assert chamber.wait_setpoint(0.5, 600.0) == 24.8
    finish(port, chamber)


def test_driver_ramp_steps_the_setpoint_in_station_time():
    clock = ManualClock()
    port, chamber = make([
        TEMP,
        (b"MODE?\r\n", b"CONSTANT\r\n"),
        TEMP, ok(b"TEMP, S24.8"),  # from the air temperature
        ok(b"TEMP, S25.8"), TEMP,  # 10 s at 6 C/min
        ok(b"TEMP, S26.0"), TEMP,  # reached: the target, the ramp ends
        TEMP,  # read_setpoint from the controller again
    ], clock)
    chamber.set_ramp_rate(6.0)
    chamber.set_setpoint(26.0)
    clock.sleep_s(10.0)
    chamber.read_temperature()
    clock.sleep_s(10.0)
    chamber.read_temperature()
    assert chamber.read_setpoint() == 25.0  # what the scripted controller says
    finish(port, chamber)


def test_no_reply_is_a_timeout_and_garbage_a_protocol_error():
    port, chamber = make([(b"TEMP?\r\n", b""), (b"TEMP?\r\n", b"24.8,25.0\r\n")])
    with pytest.raises(InstrumentTimeout, match="did not answer 'TEMP\\?'"):
        chamber.read_temperature()
    with pytest.raises(ProtocolError, match="expected 4 fields"):
        chamber.read_temperature()
    finish(port, chamber)


def test_settings_are_validated_at_the_edge():
    tcp = espec_p300.Settings.model_validate({"address": "192.168.0.30:10001"})
    serial = espec_p300.Settings.model_validate({"address": "/dev/ttyUSB0", "baudrate": 19200})
    assert (tcp.timeout_s, serial.baudrate) == (2.0, 19200)
    for bad in (
        {"address": "chamber"},
        {"address": "/dev/ttyUSB0", "baudrate": 12345},
        {"address": "10.0.0.5:10001", "poll_s": float("nan")},
        {"address": "10.0.0.5:10001", "port": 10001},
    ):
        with pytest.raises(pydantic.ValidationError):
            espec_p300.factory(bad)


def test_factory_to_nothing_listening_is_connection_lost():
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with pytest.raises(ConnectionLost, match=f"127.0.0.1:{port}"):
        espec_p300.factory({"address": f"127.0.0.1:{port}", "timeout_s": 0.5})


def test_probe_is_empty_without_alarms_and_names_them_otherwise():
    port, chamber = make([
        (b"MON?\r\n", b"25.0,,CONSTANT,0\r\n"),
        (b"MON?\r\n", b"25.0,,CONSTANT,2\r\n"),
        (b"ALARM?\r\n", b"2,17,41\r\n"),
    ])
    assert chamber.probe() == ""
    assert chamber.probe() == "alarm code 17; alarm code 41"
    finish(port, chamber)


def test_watchdog_check_raises_chamber_alarm_only_on_an_alarm():
    port, chamber = make([
        (b"MON?\r\n", b"25.0,,CONSTANT,0\r\n"),
        (b"MON?\r\n", b"31.0,,CONSTANT,1\r\n"),
        (b"ALARM?\r\n", b"1,17\r\n"),
        (b"TEMP?\r\n", b"31.0,60.0,150.0,-70.0\r\n"),
        (b"TEMP?\r\n", b"31.0,60.0,150.0,-70.0\r\n"),
    ])
    chamber.watchdog_check()
    with pytest.raises(ChamberAlarm, match="alarm code 17 at 31 C and cannot reach 60 C"):
        chamber.watchdog_check()
    finish(port, chamber)


def test_new_target_mid_ramp_continues_from_the_last_step():
    clock = ManualClock()
    port, chamber = make([
        TEMP,
        (b"MODE?\r\n", b"CONSTANT\r\n"),
        TEMP, ok(b"TEMP, S24.8"),
        ok(b"TEMP, S25.8"), TEMP,  # 10 s at 6 C/min
        (b"MODE?\r\n", b"CONSTANT\r\n"),
        ok(b"TEMP, S25.8"),  # new target: from 25.8, not from the air (24.8)
        ok(b"TEMP, S24.8"), TEMP,  # 10 s later, 1 C down
    ], clock)
    chamber.set_ramp_rate(6.0)
    chamber.set_setpoint(30.0)
    clock.sleep_s(10.0)
    chamber.read_temperature()
    chamber.set_setpoint(20.0)
    clock.sleep_s(10.0)
    chamber.read_temperature()
    finish(port, chamber)
