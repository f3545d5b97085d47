"""Watlow F4T driver against a scripted Modbus TCP server: the exact request PDUs, float32
pairs low word first (given here as hex, not computed by the code under test), units, the
driver-side ramp on the station clock, alarms and the typed errors."""

from __future__ import annotations

import pydantic
import pytest

from drivers import watlow_f4t
from drivers.errors import (
    ChamberAlarm,
    ChamberSetpointNotReached,
    ConnectionLost,
    InstrumentTimeout,
    ProtocolError,
    SetpointOutOfRange,
)
from drivers.modbus_link import ModbusLink
from drivers.watlow_f4t import WatlowF4T
from tests.drivers._fakes import (
    ManualClock,
    exception_reply,
    read_pdu,
    read_reply,
    write_many_pdu,
    write_many_reply,
    write_pdu,
)
from tests.drivers.expected_protocol import MODBUS, Pair, TcpPeer, finish


def f32(bits: int) -> list[int]:
    """A float32 bit pattern as the F4T's two registers, low word first."""
    return [bits & 0xFFFF, bits >> 16]


C25, C25_5, C26, C35, F77 = 0x41C80000, 0x41CC0000, 0x41D00000, 0x420C0000, 0x429A0000
LIMITS = Pair(read_pdu(2774, 4), read_reply(f32(0xC2200000) + f32(0x42FA0000)))  # -40..125
UNITS_C = Pair(read_pdu(6730, 1), read_reply([15]))
AUTO, OFF = 10, 62


def set_sp(bits: int, address: int = 2782) -> Pair:
    return Pair(write_many_pdu(address, f32(bits)), write_many_reply(address, 2))


def make(script, clock=None, **kw):
    server = TcpPeer(script, MODBUS)
    link = ModbusLink("127.0.0.1", server.port, timeout_s=0.5, instrument=watlow_f4t.NAME)
    return server, WatlowF4T(link, clock or ManualClock(), **kw)


def test_identify_reads_the_part_number_one_character_per_register():
    part = [ord(c) for c in "F4T1R2AA2AAAAAA"]
    server, chamber = make([Pair(read_pdu(16, 15), read_reply(part))], serial="CH-9")
    ident = chamber.identify()
    assert (ident.manufacturer, ident.model, ident.serial) == ("Watlow", "F4T1R2AA2AAAAAA", "CH-9")
    finish(server, chamber)


def test_setpoint_is_one_write_of_the_float_pair_low_word_first():
    server, chamber = make([LIMITS, UNITS_C, set_sp(C35), set_sp(C25_5)])
    chamber.set_setpoint(35.0)
    chamber.set_setpoint(25.5)
    assert chamber.setpoint_limits() == (-40.0, 125.0)  # read once
    finish(server, chamber)


def test_setpoint_outside_the_range_is_refused_before_writing():
    server, chamber = make([LIMITS, UNITS_C])
    with pytest.raises(SetpointOutOfRange, match=r"\[-40, 125\]"):
        chamber.set_setpoint(126.0)
    finish(server, chamber)


def test_controller_refusal_maps_to_setpoint_out_of_range_and_rereads_limits():
    refused = Pair(write_many_pdu(2782, f32(C35)), exception_reply(16, 3))
    server, chamber = make([LIMITS, UNITS_C, refused, LIMITS])
    with pytest.raises(SetpointOutOfRange, match="refused"):
        chamber.set_setpoint(35.0)
    assert chamber.setpoint_limits() == (-40.0, 125.0)
    finish(server, chamber)


def test_other_modbus_exceptions_stay_protocol_errors():
    refused = Pair(write_many_pdu(2782, f32(C35)), exception_reply(16, 4))
    server, chamber = make([LIMITS, UNITS_C, refused])
    with pytest.raises(ProtocolError, match="exception 4"):
        chamber.set_setpoint(35.0)
    finish(server, chamber)


def test_fahrenheit_controller_is_spoken_to_in_f():
    limits_f = Pair(read_pdu(2774, 4), read_reply(f32(0xC2200000) + f32(0x43808000)))
    server, chamber = make([
        limits_f,
        Pair(read_pdu(6730, 1), read_reply([30])),
        set_sp(F77),
        Pair(read_pdu(2820, 2), read_reply(f32(F77))),
    ])
    assert chamber.setpoint_limits() == (-40.0, 125.0)  # -40 F .. 257 F
    chamber.set_setpoint(25.0)
    assert chamber.read_temperature() == 25.0
    finish(server, chamber)


def test_unknown_units_code_is_a_protocol_error():
    server, chamber = make([LIMITS, Pair(read_pdu(6730, 1), read_reply([99]))])
    with pytest.raises(ProtocolError, match="units code 99"):
        chamber.setpoint_limits()
    finish(server, chamber)


def test_loop_2_registers_are_160_further_on():
    server, chamber = make([
        Pair(read_pdu(2934, 4), read_reply(f32(0xC2200000) + f32(0x42FA0000))),
        UNITS_C,
        set_sp(C26, 2942),
        Pair(read_pdu(2980, 2), read_reply(f32(C25))),
        Pair(read_pdu(2974, 1), read_reply([AUTO])),
    ], loop=2)
    chamber.set_setpoint(26.0)
    assert chamber.read_temperature() == 25.0
    assert chamber.is_running()
    finish(server, chamber)


def test_run_terminates_a_running_profile_then_sets_auto():
    server, chamber = make([
        Pair(read_pdu(16568, 1), read_reply([149])),
        Pair(write_pdu(16566, 148), write_pdu(16566, 148)),
        Pair(write_pdu(2730, AUTO), write_pdu(2730, AUTO)),
        Pair(read_pdu(16568, 1), read_reply([61])),
        Pair(write_pdu(2730, AUTO), write_pdu(2730, AUTO)),
        Pair(write_pdu(2730, OFF), write_pdu(2730, OFF)),
        Pair(read_pdu(2814, 1), read_reply([OFF])),
    ])
    chamber.run()
    chamber.run()
    chamber.stop()
    assert not chamber.is_running()
    finish(server, chamber)


def test_driver_ramp_writes_the_ramped_setpoint_on_the_station_clock():
    clock = ManualClock()
    pv = Pair(read_pdu(2820, 2), read_reply(f32(C25)))
    server, chamber = make([
        LIMITS, UNITS_C,
        Pair(read_pdu(2814, 1), read_reply([AUTO])),  # running: the ramp starts now
        pv, set_sp(C25),  # from the air temperature
        set_sp(C25_5), pv,  # 5 s at 6 C/min: 0.5 C further
        pv,  # 0.5 s later: 0.05 C is below the step, nothing written
        set_sp(C26), pv,  # past the target: the target, and the ramp ends
        Pair(read_pdu(2782, 2), read_reply(f32(C26))),
    ], clock)
    chamber.set_ramp_rate(6.0)
    chamber.set_setpoint(26.0)
    clock.sleep_s(5.0)
    assert chamber.read_temperature() == 25.0
    clock.sleep_s(0.5)
    chamber.read_temperature()
    clock.sleep_s(20.0)
    chamber.read_temperature()
    assert chamber.read_setpoint() == 26.0
    finish(server, chamber)


def test_ramp_waits_for_run_when_stopped():
    clock = ManualClock()
    server, chamber = make([
        LIMITS, UNITS_C,
        Pair(read_pdu(2814, 1), read_reply([OFF])),  # stopped: nothing written yet
        Pair(read_pdu(2820, 2), read_reply(f32(C25))),  # run(): from the air
        set_sp(C25),
        Pair(read_pdu(16568, 1), read_reply([61])),
        Pair(write_pdu(2730, AUTO), write_pdu(2730, AUTO)),
    ], clock)
    chamber.set_ramp_rate(6.0)
    chamber.set_setpoint(35.0)
    assert chamber.read_setpoint() == 35.0  # the target, not the ramp
    clock.sleep_s(100.0)  # time stopped does not count
    chamber.run()
    finish(server, chamber)


def test_wait_setpoint_raises_chamber_alarm_on_an_active_alarm():
    server, chamber = make([
        Pair(read_pdu(2782, 2), read_reply(f32(C35))),
        UNITS_C,
        Pair(read_pdu(2814, 1), read_reply([AUTO])),
        Pair(read_pdu(2820, 2), read_reply(f32(C25))),
        Pair(read_pdu(1356, 1), read_reply([61])),
        Pair(read_pdu(1456, 1), read_reply([53])),  # alarm 2 low
    ], alarm_count=2)
    with pytest.raises(ChamberAlarm, match="low alarm on alarm 2"):
        chamber.wait_setpoint(0.5, 600.0)
    finish(server, chamber)


def test_wait_setpoint_times_out_in_station_time():
    clock = ManualClock()
    poll = [
        Pair(read_pdu(2820, 2), read_reply(f32(C25))),
        Pair(read_pdu(1356, 1), read_reply([61])),
    ]
    server, chamber = make([
        Pair(read_pdu(2782, 2), read_reply(f32(C35))),
        UNITS_C,
        Pair(read_pdu(2814, 1), read_reply([AUTO])),
        *poll * 4,  # at 0, 10, 20 and 30 s
    ], clock, poll_s=10.0, alarm_count=1)
    with pytest.raises(ChamberSetpointNotReached, match="within 25 s") as err:
        chamber.wait_setpoint(0.5, 25.0)
    assert not isinstance(err.value, ChamberAlarm)
    assert clock.slept_s == 30.0
    finish(server, chamber)


def test_safe_state_clamps_and_runs():
    limits = Pair(read_pdu(2774, 4), read_reply(f32(C26) + f32(0x42FA0000)))  # 26..125
    server, chamber = make([
        limits, UNITS_C, set_sp(C26),
        Pair(read_pdu(16568, 1), read_reply([61])),
        Pair(write_pdu(2730, AUTO), write_pdu(2730, AUTO)),
    ])
    chamber.safe_state(25.0)
    finish(server, chamber)


def test_lost_connection_and_late_reply_are_typed():
    server, chamber = make([
        Pair(read_pdu(2814, 1), None, close=True),
        Pair(read_pdu(2814, 1), read_reply([AUTO]), delay_s=0.8),
    ])
    with pytest.raises(ConnectionLost):
        chamber.is_running()
    with pytest.raises(InstrumentTimeout):
        chamber.is_running()
    finish(server, chamber)


def test_settings_are_validated_at_the_edge():
    ok = watlow_f4t.Settings.model_validate({"address": "10.0.0.5:502"})
    assert (ok.timeout_s, ok.loop, ok.alarm_count) == (1.0, 1, 6)
    for bad in (
        {"address": "10.0.0.5"},
        {"address": "10.0.0.5:502", "loop": 5},
        {"address": "10.0.0.5:502", "timeout_s": float("inf")},
        {"address": "10.0.0.5:502", "baud": 9600},
    ):
        with pytest.raises(pydantic.ValidationError):
            watlow_f4t.factory(bad)


def test_factory_connects_or_raises_connection_lost():
    server = TcpPeer([], MODBUS)
    chamber = watlow_f4t.factory({"address": f"127.0.0.1:{server.port}", "timeout_s": 0.5})
    chamber.close()
    server.close()
    with pytest.raises(ConnectionLost, match="cannot connect"):
        watlow_f4t.factory({"address": f"127.0.0.1:{server.port}", "timeout_s": 0.5})


def test_probe_reads_each_alarm_state():
    server, chamber = make([
        Pair(read_pdu(1356, 1), read_reply([88])),
        Pair(read_pdu(1456, 1), read_reply([12])),
        Pair(read_pdu(1356, 1), read_reply([37])),
        Pair(read_pdu(1456, 1), read_reply([61])),
    ], alarm_count=2)
    assert chamber.probe() == ""  # startup and blocked are not alarms
    assert chamber.probe() == "a high alarm on alarm 1"
    finish(server, chamber)
