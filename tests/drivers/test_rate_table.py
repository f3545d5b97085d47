"""Rate table driver against a scripted Modbus TCP server: exact request bytes, decoding,
waits on the station clock, faults and link failures as typed exceptions."""

from __future__ import annotations

import time

import pytest

from drivers.errors import (
    ConnectionLost,
    InstrumentError,
    InstrumentTimeout,
    InterlockOpen,
    TableFault,
)
from drivers.modbus_link import ModbusLink
from drivers.rate_table import ModbusRateTable
from drivers.rate_table_map import Control, Fault, Status
from tests.drivers._fakes import (
    ManualClock,
    exception_reply,
    pair,
    read_pdu,
    read_reply,
    str_regs,
    write_many_pdu,
    write_many_reply,
    write_pdu,
)
from tests.drivers.expected_protocol import MODBUS, Pair, TcpPeer, finish

READY_ENABLED = Status.READY | Status.ENABLED


def status_regs(bits=READY_ENABLED, fault=0, counts=0, pos_mdeg=0, rate_mdps=0, t_us=0):
    return [int(bits), fault, *pair(counts), *pair(pos_mdeg), *pair(rate_mdps), *pair(t_us)]


def status_read(**kw) -> Pair:
    return Pair(read_pdu(20, 10), read_reply(status_regs(**kw)))


def cmd_regs(mode=0, pos=0, rate=0, accel=100_000, move_ms=0):
    return [mode, *pair(pos), *pair(rate), *pair(accel), *pair(move_ms)]


def make(script, timeout_s=0.5, clock=None, poll_s=0.125):
    server = TcpPeer(script, MODBUS)
    link = ModbusLink("127.0.0.1", server.port, timeout_s=timeout_s, instrument="rate table")
    return server, ModbusRateTable(link, clock or ManualClock(), poll_s=poll_s)


def test_identify_reads_the_three_strings_in_one_request():
    regs = str_regs("Acutronic AC1120", 8) + str_regs("RT-0042", 8) + str_regs("2.1.7", 4)
    server, table = make([Pair(bytes.fromhex("03 0028 0014"), read_reply(regs))])
    ident = table.identify()
    assert (ident.manufacturer, ident.model, ident.serial, ident.firmware) == (
        "Acutronic", "Acutronic AC1120", "RT-0042", "2.1.7"
    )
    finish(server, table)


def test_status_snapshot_decodes_signs_and_unwraps_counters():
    server, table = make([
        status_read(bits=READY_ENABLED | Status.AT_RATE | Status.MOVING, counts=0xFFFF_FFF0,
                    pos_mdeg=-12_345, rate_mdps=-100_250, t_us=0xFFFF_FF00),
        status_read(counts=0x10, t_us=0x100),
    ])
    s = table.read_status()
    assert s.enabled and s.ready and s.at_rate and s.moving
    assert not (s.fault or s.in_position or s.interlock_open)
    assert s.position_deg == -12.345 and s.rate_dps == -100.25
    assert s.encoder_counts == 0xFFFF_FFF0
    assert s.controller_time_s == pytest.approx(0xFFFF_FF00 * 1e-6)
    assert s.controller_time_resolution_s == 1e-6  # one count of the us clock register
    s2 = table.read_status()
    assert s2.encoder_counts == 0x10  # raw, as the contract says
    assert s2.encoder_counts_unwrapped - s.encoder_counts_unwrapped == 0x20
    assert s2.controller_time_s - s.controller_time_s == pytest.approx(0x200 * 1e-6)
    finish(server, table)


def test_set_rate_writes_mode_and_rate_in_one_request_keeping_other_commands():
    before = cmd_regs(mode=1, pos=90_000, rate=0, accel=200_000, move_ms=3500)
    after = cmd_regs(mode=2, pos=90_000, rate=-150_500, accel=50_000, move_ms=3500)
    server, table = make([
        Pair(read_pdu(1, 9), read_reply(before)),
        Pair(write_many_pdu(1, after), write_many_reply(1, 9)),
        status_read(),
    ])
    table.set_rate(-150.5, accel_dps2=50.0)
    finish(server, table)


def test_move_to_with_move_time_writes_move_time_ms():
    before = cmd_regs(mode=2, rate=10_000, accel=200_000)
    after = cmd_regs(mode=1, pos=-90_000, rate=10_000, accel=200_000, move_ms=3500)
    server, table = make([
        Pair(read_pdu(1, 9), read_reply(before)),
        Pair(write_many_pdu(1, after), write_many_reply(1, 9)),
        status_read(),
    ])
    table.move_to(-90.0, move_time_s=3.5)
    finish(server, table)


def test_move_to_with_accel_writes_accel_limit_and_zero_move_time():
    before = cmd_regs(mode=1, pos=5_000, accel=200_000, move_ms=3500)
    after = cmd_regs(mode=1, pos=90_000, accel=30_000, move_ms=0)
    server, table = make([
        Pair(read_pdu(1, 9), read_reply(before)),
        Pair(write_many_pdu(1, after), write_many_reply(1, 9)),
        status_read(),
    ])
    table.move_to(90.0, accel_dps2=30.0)
    finish(server, table)


def test_move_to_rejects_both_accel_and_move_time_without_touching_the_table():
    server, table = make([])
    with pytest.raises(ValueError, match="either"):
        table.move_to(1.0, accel_dps2=10.0, move_time_s=2.0)
    finish(server, table)


def test_enable_sets_enable_bit_keeping_none_of_the_edge_bits():
    server, table = make([
        status_read(bits=Status.READY),
        Pair(read_pdu(0, 1), read_reply([int(Control.HALT | Control.FAULT_RESET)])),
        Pair(write_pdu(0, int(Control.ENABLE)), write_pdu(0, int(Control.ENABLE))),
        status_read(bits=READY_ENABLED),
    ])
    table.enable()
    finish(server, table)


def test_enable_with_interlock_open_raises_before_writing():
    server, table = make([status_read(bits=Status.INTERLOCK_OPEN)])
    with pytest.raises(InterlockOpen, match="close it"):
        table.enable()
    finish(server, table)


@pytest.mark.parametrize(
    ("fault", "text"),
    [(Fault.FOLLOWING_ERROR, "following error"), (Fault.ESTOP, "emergency stop"),
     (Fault.ENCODER_LOSS, "encoder")],
)
def test_fault_during_wait_raises_table_fault_with_code_and_advice(fault, text):
    before = cmd_regs()
    after = cmd_regs(mode=2, rate=100_000)
    server, table = make([
        Pair(read_pdu(1, 9), read_reply(before)),
        Pair(write_many_pdu(1, after), write_many_reply(1, 9)),
        status_read(bits=READY_ENABLED | Status.MOVING),
        status_read(bits=READY_ENABLED | Status.MOVING, rate_mdps=50_000),
        status_read(bits=Status.FAULT, fault=int(fault)),
    ])
    table.set_rate(100.0)
    with pytest.raises(TableFault, match=text) as info:
        table.wait_at_rate(10.0)
    assert info.value.fault_code == fault
    assert not isinstance(info.value, InterlockOpen)
    finish(server, table)


def test_wait_at_rate_ignores_a_stale_at_rate_bit_from_the_previous_rate():
    server, table = make([
        Pair(read_pdu(1, 9), read_reply(cmd_regs())),
        Pair(write_many_pdu(1, cmd_regs(mode=2, rate=100_000)), write_many_reply(1, 9)),
        status_read(bits=READY_ENABLED | Status.AT_RATE, rate_mdps=10_000),
        status_read(bits=READY_ENABLED | Status.AT_RATE, rate_mdps=10_000),
        status_read(bits=READY_ENABLED | Status.AT_RATE, rate_mdps=100_004),
    ])
    table.set_rate(100.0)
    s = table.wait_at_rate(5.0)
    assert s.rate_dps == pytest.approx(100.004)
    finish(server, table)


def test_wait_in_position_times_out_in_station_time():
    clock = ManualClock()
    n_polls = 9  # 1.0 s at 0.125 s polls, plus the first
    server, table = make(
        [status_read(bits=READY_ENABLED | Status.MOVING) for _ in range(n_polls)], clock=clock
    )
    with pytest.raises(InstrumentTimeout, match="within 1 s"):
        table.wait_in_position(1.0)
    assert clock.now_s() == 1.0
    finish(server, table)


def test_a_wait_ends_at_once_when_the_clock_is_interrupted():
    """An abort (operator, SIGTERM) interrupts the station clock: a step waiting for a long
    move must not wait the move out before the safe-state pass may stop the table."""
    clock = ManualClock()
    server, table = make([status_read(bits=READY_ENABLED | Status.MOVING)], clock=clock)
    clock.interrupted = True  # type: ignore[attr-defined]
    s = table.wait_in_position(60.0)
    assert s.moving and clock.now_s() == 0.0
    finish(server, table)


def test_safe_state_waits_for_rest_before_disabling_even_when_interrupted():
    """After an abort the safe state still halts the table and waits for it to be at rest
    before the drive is disabled (a lockstep bench passes no time but the station's waits:
    disabled at once, the table was left turning and the safe state failed)."""
    clock = ManualClock()
    halt = int(Control.ENABLE | Control.HALT)
    server, table = make([
        status_read(bits=READY_ENABLED | Status.MOVING, rate_mdps=20_000),
        Pair(write_pdu(0, halt), write_pdu(0, halt)),
        status_read(bits=READY_ENABLED | Status.MOVING, rate_mdps=5_000),
        status_read(),
        Pair(write_pdu(0, 0), write_pdu(0, 0)),
    ], clock=clock)
    clock.interrupted = True  # type: ignore[attr-defined]
    table.safe_state()
    assert clock.now_s() == 0.125  # one poll while it came to rest
    finish(server, table)


def test_refused_command_raises_instrument_error_naming_the_values():
    server, table = make([
        Pair(read_pdu(1, 9), read_reply(cmd_regs())),
        Pair(write_many_pdu(1, cmd_regs(mode=1, pos=10_000, accel=9_000_000)),
                 exception_reply(16, 3)),
    ])
    with pytest.raises(InstrumentError, match="refused.*9000"):
        table.move_to(10.0, accel_dps2=9000.0)
    finish(server, table)


def test_dropped_connection_raises_connection_lost():
    server, table = make([Pair(read_pdu(20, 10), None, close=True)])
    t0 = time.monotonic()
    with pytest.raises(ConnectionLost, match="dropped"):
        table.read_status()
    assert time.monotonic() - t0 < 1.0
    finish(server, table)


def test_reply_later_than_timeout_raises_instrument_timeout_then_recovers():
    late = Pair(read_pdu(20, 10), read_reply(status_regs()), delay_s=0.6)
    server, table = make([late, status_read(rate_mdps=1_000)], timeout_s=0.3)
    t0 = time.monotonic()
    with pytest.raises(InstrumentTimeout, match="did not answer"):
        table.read_status()
    assert time.monotonic() - t0 < 0.3 + 0.4
    time.sleep(0.4)  # the late reply lands on the closed socket, not on the next request
    assert table.read_status().rate_dps == 1.0
    finish(server, table)


def test_connect_to_nothing_raises_connection_lost_with_advice():
    server = TcpPeer([], MODBUS)
    port = server.port
    server.close()
    link = ModbusLink("127.0.0.1", port, timeout_s=0.3, instrument="rate table")
    with pytest.raises(ConnectionLost, match="powered"):
        ModbusRateTable(link, ManualClock()).read_status()


def test_next_request_after_a_drop_reconnects():
    server, table = make([
        Pair(read_pdu(20, 10), None, close=True),
        status_read(rate_mdps=2_500),
    ])
    with pytest.raises(ConnectionLost):
        table.read_status()
    assert table.read_status().rate_dps == 2.5
    finish(server, table)


def test_drivers_satisfy_their_protocols():
    from drivers.chamber import ModbusChamber
    from drivers.protocols import Chamber, RateTable

    link = ModbusLink("127.0.0.1", 1, timeout_s=0.1)
    assert isinstance(ModbusRateTable(link, ManualClock()), RateTable)
    assert isinstance(ModbusChamber(link, ManualClock()), Chamber)
