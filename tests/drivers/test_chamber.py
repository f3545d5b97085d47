"""Chamber driver against a scripted Modbus TCP server: exact request bytes, signed tenths,
limits, waits on the station clock and the stuck-chamber fault."""

from __future__ import annotations

import pytest

from drivers.chamber import ModbusChamber
from drivers.chamber_map import State
from drivers.errors import (
    ChamberSetpointNotReached,
    ConnectionLost,
    InstrumentError,
    SetpointOutOfRange,
)
from drivers.modbus_link import ModbusLink
from tests.drivers._fakes import (
    ManualClock,
    exception_reply,
    read_pdu,
    read_reply,
    str_regs,
    write_pdu,
)
from tests.drivers.expected_protocol import MODBUS, Pair, TcpPeer, finish

LIMITS = Pair(read_pdu(602, 2), read_reply([-400 & 0xFFFF, 1500]))  # -40.0 .. 150.0 C


def make(script, clock=None, poll_s=1.0):
    server = TcpPeer(script, MODBUS)
    link = ModbusLink("127.0.0.1", server.port, timeout_s=0.5, instrument="thermal chamber")
    return server, ModbusChamber(link, clock or ManualClock(), poll_s=poll_s)


def test_identify():
    regs = str_regs("Watlow F4T", 8) + str_regs("CH-77", 8) + str_regs("4.2", 4)
    server, chamber = make([Pair(read_pdu(40, 20), read_reply(regs))])
    ident = chamber.identify()
    assert (ident.manufacturer, ident.model, ident.serial, ident.firmware) == (
        "Watlow", "Watlow F4T", "CH-77", "4.2")
    finish(server, chamber)


def test_negative_setpoint_is_written_as_signed_tenths_and_limits_read_once():
    server, chamber = make([
        LIMITS,
        Pair(write_pdu(300, -125), write_pdu(300, -125)),
        Pair(write_pdu(300, 851), write_pdu(300, 851)),
    ])
    chamber.set_setpoint(-12.5)
    chamber.set_setpoint(85.1)
    assert chamber.setpoint_limits() == (-40.0, 150.0)
    finish(server, chamber)


def test_setpoint_outside_limits_is_refused_before_sending():
    server, chamber = make([LIMITS])
    with pytest.raises(SetpointOutOfRange, match=r"\[-40, 150\]"):
        chamber.set_setpoint(151.0)
    finish(server, chamber)


def test_controller_refusal_maps_to_setpoint_out_of_range():
    server, chamber = make([LIMITS, Pair(write_pdu(300, 700), exception_reply(6, 3))])
    with pytest.raises(SetpointOutOfRange, match="refused"):
        chamber.set_setpoint(70.0)
    finish(server, chamber)


def test_reads_decode_signed_tenths_and_state():
    server, chamber = make([
        Pair(read_pdu(100, 1), read_reply([-53 & 0xFFFF])),
        Pair(read_pdu(300, 1), read_reply([250])),
        Pair(read_pdu(200, 1), read_reply([int(State.RAMPING)])),
        Pair(read_pdu(1000, 1), read_reply([1])),
    ])
    assert chamber.read_temperature() == -5.3
    assert chamber.read_setpoint() == 25.0
    assert chamber.read_state() == State.RAMPING
    assert chamber.is_running()
    finish(server, chamber)


def test_ramp_run_stop_bytes():
    server, chamber = make([
        Pair(write_pdu(1001, 25), write_pdu(1001, 25)),
        Pair(write_pdu(1000, 1), write_pdu(1000, 1)),
        Pair(write_pdu(1000, 0), write_pdu(1000, 0)),
    ])
    chamber.set_ramp_rate(2.5)
    chamber.run()
    chamber.stop()
    with pytest.raises(ValueError, match="ramp rate"):
        chamber.set_ramp_rate(-1)
    finish(server, chamber)


def _pv(tenths):
    return Pair(read_pdu(100, 1), read_reply([tenths & 0xFFFF]))


def _state(state):
    return Pair(read_pdu(200, 1), read_reply([int(state)]))


def test_wait_setpoint_returns_once_within_band():
    clock = ManualClock()
    server, chamber = make([
        Pair(read_pdu(300, 1), read_reply([850])),
        Pair(read_pdu(1000, 1), read_reply([1])),
        _pv(600), _state(State.RAMPING),
        _pv(800), _state(State.RAMPING),
        _pv(846),
    ], clock=clock)
    assert chamber.wait_setpoint(0.5, 600.0) == 84.6
    assert clock.now_s() == 2.0
    finish(server, chamber)


def test_stuck_chamber_times_out_in_station_time_with_the_temperatures():
    clock = ManualClock()
    polls = [e for _ in range(5) for e in (_pv(400), _state(State.RAMPING))]
    server, chamber = make(
        [Pair(read_pdu(300, 1), read_reply([850])),
         Pair(read_pdu(1000, 1), read_reply([1])),
         *polls], clock=clock, poll_s=0.5)
    with pytest.raises(ChamberSetpointNotReached, match=r"85 \+/- 0.5 C within 2 s \(now 40 C\)"):
        chamber.wait_setpoint(0.5, 2.0)
    assert clock.now_s() == 2.0
    finish(server, chamber)


def test_chamber_fault_state_ends_the_wait_at_once():
    clock = ManualClock()
    server, chamber = make([
        Pair(read_pdu(300, 1), read_reply([850])),
        Pair(read_pdu(1000, 1), read_reply([1])),
        _pv(400), _state(State.FAULT),
    ], clock=clock)
    with pytest.raises(ChamberSetpointNotReached, match="fault"):
        chamber.wait_setpoint(0.5, 3600.0)
    assert clock.now_s() == 0.0
    finish(server, chamber)


def test_wait_on_a_stopped_chamber_says_to_run_it():
    server, chamber = make([
        Pair(read_pdu(300, 1), read_reply([850])),
        Pair(read_pdu(1000, 1), read_reply([0])),
    ])
    with pytest.raises(InstrumentError, match="run"):
        chamber.wait_setpoint(0.5, 10.0)
    finish(server, chamber)


def test_dropped_link_is_connection_lost():
    server, chamber = make([Pair(read_pdu(100, 1), None, close=True)])
    with pytest.raises(ConnectionLost):
        chamber.read_temperature()
    finish(server, chamber)
