"""ACUTROL driver against a scripted TCP line server: exact command strings on the wire,
reply decoding, derived encoder counts, waits on the station clock, and every error reply,
lost connection and late reply as its typed exception."""

from __future__ import annotations

import time

import pytest
from pydantic import ValidationError

from drivers.acutrol import AcutrolRefused, AcutrolTable, Settings, factory
from drivers.acutrol_codes import StatusBit
from drivers.errors import (
    ConnectionLost,
    InstrumentTimeout,
    InterlockOpen,
    ProtocolError,
    SetpointOutOfRange,
    TableFault,
)
from drivers.protocols import RateTable
from drivers.tcp_lines import LineLink
from tests.drivers._fakes import ManualClock
from tests.drivers.expected_protocol import Pair, TcpPeer, finish

STATUS_Q = b":read:pos? 1;rate? 1;:status? 1;:fault? 1;:system:time?\r\n"
OK = b"OK\r\n"
READY_CLOSED = StatusBit.READY | StatusBit.CLOSED
LIMITS = Pair(b":limit:absolute? 1\r\n", b"1000.000,2000.000,0.000,-1e6,1e6,1100.000\r\n")


def status(pos=0.0, rate=0.0, word=READY_CLOSED, fault=0, t_s=1.0) -> Pair:
    return Pair(STATUS_Q, f"{pos};{rate};{int(word)};{fault};{t_s}\r\n".encode())


def make(script, timeout_s=0.5, clock=None, cpr=1 << 20):
    server = TcpPeer(script)
    link = LineLink("127.0.0.1", server.port, timeout_s=timeout_s, instrument="rate table")
    return server, AcutrolTable(link, clock or ManualClock(), counts_per_rev=cpr, poll_s=0.125)


def test_identify_parses_idn():
    server, table = make([Pair(b"*IDN?\r\n", b"Acutronic,ACUTROL3000,AC-4711,3.2.1\r\n")])
    ident = table.identify()
    assert (ident.manufacturer, ident.model, ident.serial, ident.firmware) == (
        "Acutronic", "ACUTROL3000", "AC-4711", "3.2.1"
    )
    finish(server, table)


def test_status_is_one_request_and_counts_are_derived_from_position():
    cpr = 1 << 20
    pos = -12345 * 360.0 / cpr  # exactly -12345 counts
    word = READY_CLOSED | StatusBit.AT_RATE | StatusBit.MOVING
    server, table = make([status(pos=f"{pos:.7f}", rate=-100.25, word=word, t_s=123.456789)])
    s = table.read_status()
    assert s.enabled and s.ready and s.at_rate and s.moving
    assert not (s.fault or s.in_position or s.interlock_open)
    assert s.encoder_counts_unwrapped == -12345
    assert s.encoder_counts == (1 << 32) - 12345  # raw: wrapped to 32 bits as the contract says
    assert s.rate_dps == -100.25 and s.controller_time_s == 123.456789
    assert s.position_deg == pytest.approx(pos, abs=1e-7)
    finish(server, table)


def test_set_rate_sends_limit_mode_and_demand_on_one_line():
    server, table = make([
        LIMITS,
        Pair(b":limit:acc rate,1,50.000000;:mode:rate 1;:demand:rate 1,-150.500000\r\n", OK),
        status(),
    ])
    table.set_rate(-150.5, accel_dps2=50.0)
    finish(server, table)


def test_set_rate_without_accel_keeps_the_controllers_limit():
    server, table = make([
        LIMITS, Pair(b":mode:rate 1;:demand:rate 1,30.000000\r\n", OK), status(),
    ])
    table.set_rate(30.0)
    finish(server, table)


def test_set_rate_beyond_the_reported_limit_is_refused_before_sending():
    server, table = make([LIMITS])
    with pytest.raises(ValueError, match="beyond the table's limit of 1000"):
        table.set_rate(1200.0)
    finish(server, table)


def test_move_to_with_move_time_sets_a_triangular_move_of_that_length():
    # 10 deg -> 100 deg in 3 s: acceleration 4*90/9 = 40 deg/s^2, peak rate 2*90/3 = 60 deg/s
    server, table = make([
        status(pos=10.0),
        Pair(b":limit:acc pos,1,40.000000;:limit:rate pos,1,60.000000;:mode:position 1;"
             b":demand:position 1,100.000000\r\n", OK),
        status(pos=10.0),
    ])
    table.move_to(100.0, move_time_s=3.0)
    finish(server, table)


def test_move_to_with_accel_sends_the_position_modes_limit():
    server, table = make([
        Pair(b":limit:acc pos,1,30.000000;:mode:position 1;:demand:position 1,-90.000000\r\n",
             OK),
        status(),
    ])
    table.move_to(-90.0, accel_dps2=30.0)
    finish(server, table)


def test_zero_encoder_is_the_drivers_zero_for_positions_demands_and_counts():
    server, table = make([
        status(pos=200.0),
        status(pos=290.0),
        Pair(b":mode:position 1;:demand:position 1,380.000000\r\n", OK),
        status(pos=290.0),
    ])
    table.zero_encoder()
    s = table.read_status()
    assert s.position_deg == pytest.approx(90.0)
    assert s.encoder_counts_unwrapped == (1 << 20) // 4
    table.move_to(180.0)
    finish(server, table)


def test_enable_closes_the_axis_interlock_and_waits_for_it():
    server, table = make([
        status(word=StatusBit.READY),
        Pair(b":interlock:close 1\r\n", OK),
        status(word=StatusBit.READY),
        status(word=READY_CLOSED),
    ])
    table.enable()
    finish(server, table)


def test_enable_with_safety_interlock_open_raises_before_sending():
    server, table = make([status(word=StatusBit.SAFETY_OPEN)])
    with pytest.raises(InterlockOpen, match="close it"):
        table.enable()
    finish(server, table)


def test_error_reply_safety_open_raises_interlock_open():
    server, table = make([
        status(word=StatusBit.READY),
        Pair(b":interlock:close 1\r\n", b'ERR 201,"Safety interlock open: close the door"\r\n'),
        status(word=StatusBit.SAFETY_OPEN),
    ])
    with pytest.raises(InterlockOpen):
        table.enable()
    finish(server, table)


def test_error_reply_fault_latched_raises_table_fault_with_its_code():
    server, table = make([
        status(word=StatusBit.READY),
        Pair(b":interlock:close 1\r\n", b'ERR 202,"Fault latched: reset the interlock"\r\n'),
        status(word=StatusBit.FAULT, fault=2),
    ])
    with pytest.raises(TableFault, match="position error trip") as info:
        table.enable()
    assert info.value.fault_code == 2 and not isinstance(info.value, InterlockOpen)
    finish(server, table)


def test_error_reply_out_of_range_raises_setpoint_out_of_range():
    server, table = make([
        Pair(b":limit:acc pos,1,9000.000000;:mode:position 1;:demand:position 1,1.000000\r\n",
             b'ERR -222,"Data out of range: acceleration limit 9000 not in (0, 2000]"\r\n'),
    ])
    with pytest.raises(SetpointOutOfRange, match="9000"):
        table.move_to(1.0, accel_dps2=9000.0)
    finish(server, table)


def test_other_error_reply_raises_acutrol_refused_with_the_code():
    server, table = make([
        Pair(b":interlock:reset 1\r\n", b'ERR 203,"Emergency stop pressed"\r\n'),
        status(word=StatusBit.FAULT | StatusBit.ESTOP, fault=4),
    ])
    with pytest.raises(TableFault, match="emergency stop") as info:
        table.reset_fault()
    assert info.value.fault_code == 4
    finish(server, table)
    server, table = make([Pair(b":interlock:open 1\r\n", b'ERR -113,"Undefined header"\r\n')])
    with pytest.raises(AcutrolRefused, match="-113") as refused:
        table.disable()
    assert refused.value.code == -113 and isinstance(refused.value, ProtocolError)
    finish(server, table)


@pytest.mark.parametrize("reply", [b"1.0;2.0\r\n", b"1.0;x;3;0;1.0\r\n", b"ERRxyz\r\n"])
def test_malformed_replies_raise_protocol_error(reply):
    server, table = make([Pair(STATUS_Q, reply)])
    with pytest.raises(ProtocolError):
        table.read_status()
    finish(server, table)


def test_fault_during_wait_raises_table_fault_with_code_and_text():
    server, table = make([
        LIMITS,
        Pair(b":mode:rate 1;:demand:rate 1,100.000000\r\n", OK),
        status(word=READY_CLOSED | StatusBit.MOVING),
        status(word=READY_CLOSED | StatusBit.MOVING, rate=50.0),
        status(word=StatusBit.FAULT, fault=3),
    ])
    table.set_rate(100.0)
    with pytest.raises(TableFault, match="transducer") as info:
        table.wait_at_rate(10.0)
    assert info.value.fault_code == 3
    finish(server, table)


def test_wait_at_rate_ignores_a_stale_at_rate_and_times_out_in_station_time():
    clock = ManualClock()
    stale = status(word=READY_CLOSED | StatusBit.AT_RATE, rate=10.0)
    server, table = make(
        [LIMITS, Pair(b":mode:rate 1;:demand:rate 1,100.000000\r\n", OK), status()]
        + [stale] * 9,
        clock=clock,
    )
    table.set_rate(100.0)
    with pytest.raises(InstrumentTimeout, match="within 1 s"):
        table.wait_at_rate(1.0)
    assert clock.now_s() == 1.0
    finish(server, table)


def test_safe_state_stops_then_opens_the_interlock_and_is_quiet_when_already_safe():
    server, table = make([
        status(word=READY_CLOSED | StatusBit.MOVING, rate=100.0),
        Pair(b":mode:rate 1;:demand:rate 1,0.000000\r\n", OK),
        status(word=READY_CLOSED | StatusBit.MOVING, rate=40.0),
        status(word=READY_CLOSED),
        Pair(b":interlock:open 1\r\n", OK),
        status(word=StatusBit.READY),
        Pair(b":interlock:open 1\r\n", OK),
    ])
    table.safe_state()
    table.safe_state()
    finish(server, table)


def test_dropped_connection_raises_connection_lost_and_the_next_request_reconnects():
    server, table = make([Pair(STATUS_Q, None, close=True), status(rate=2.5)])
    with pytest.raises(ConnectionLost, match="dropped"):
        table.read_status()
    assert table.read_status().rate_dps == 2.5
    finish(server, table)


def test_reply_later_than_timeout_raises_instrument_timeout_then_recovers():
    late = Pair(STATUS_Q, b"0;0;3;0;1.0\r\n", delay_s=0.6)
    server, table = make([late, status(rate=1.0)], timeout_s=0.3)
    t0 = time.monotonic()
    with pytest.raises(InstrumentTimeout, match="did not answer"):
        table.read_status()
    assert time.monotonic() - t0 < 0.3 + 0.4
    time.sleep(0.4)  # the late reply lands on the closed socket, not on the next request
    assert table.read_status().rate_dps == 1.0
    finish(server, table)


def test_connect_to_nothing_raises_connection_lost_with_advice():
    server = TcpPeer([])
    port = server.port
    server.close()
    with pytest.raises(ConnectionLost, match="powered"):
        factory({"address": f"127.0.0.1:{port}", "timeout_s": 0.3})


def test_settings_refuse_bad_addresses_and_unknown_keys():
    assert Settings.model_validate({"address": "10.0.0.5:9888"}).axis == 1
    for bad in ({"address": "10.0.0.5"}, {"address": "10.0.0.5:0"},
                {"address": "h:1", "driver": "acutrol"}, {"address": "h:1", "timeout_s": -1}):
        with pytest.raises(ValidationError):
            Settings.model_validate(bad)


def test_driver_satisfies_the_rate_table_protocol():
    link = LineLink("127.0.0.1", 1, timeout_s=0.1)
    assert isinstance(AcutrolTable(link, ManualClock()), RateTable)
