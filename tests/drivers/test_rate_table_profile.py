"""The Modbus servo driver with a user-defined profile (servo-lowword-example): other
addresses, low word first, other scales and bit numbers, exact requests on the wire."""

from __future__ import annotations

import pytest

from drivers.errors import InstrumentError, InterlockOpen, TableFault
from drivers.modbus_link import ModbusLink
from drivers.rate_table import ModbusRateTable
from drivers.servo_profile import load_profile
from tests.drivers._fakes import (
    ManualClock,
    exception_reply,
    read_pdu,
    read_reply,
    str_regs,
    write_many_pdu,
    write_many_reply,
    write_pdu,
)
from tests.drivers.expected_protocol import MODBUS, Pair, TcpPeer, finish

PROFILE = load_profile("servo-lowword-example")
READY, ENABLED, FAULT, IN_POS, AT_RATE, MOVING, INTERLOCK = (
    1 << 15, 1 << 14, 1 << 13, 1 << 10, 1 << 11, 1 << 9, 1 << 0
)
ENABLE, HALT, FAULT_RESET, ZERO = 1 << 8, 1 << 9, 1 << 15, 1 << 12


def lo_first(value: int) -> list[int]:
    value &= 0xFFFFFFFF
    return [value & 0xFFFF, value >> 16]


def status_regs(bits=READY | ENABLED, fault=0, t_ms=0, pos_e4=0, rate_e2=0, counts=0):
    return [bits, fault, *lo_first(t_ms), *lo_first(pos_e4), *lo_first(rate_e2),
            *lo_first(counts)]


def status_read(**kw) -> Pair:
    return Pair(read_pdu(1200, 10), read_reply(status_regs(**kw)))


def cmd_regs(mode=0, gap=0x5A5A, rate_e2=0, pos_e4=0, accel_e1=1000, move_e2=0):
    return [mode, gap, *lo_first(rate_e2), *lo_first(pos_e4), *lo_first(accel_e1), move_e2]


def make(script, clock=None):
    server = TcpPeer(script, MODBUS)
    link = ModbusLink("127.0.0.1", server.port, timeout_s=0.5, instrument="rate table")
    table = ModbusRateTable(link, clock or ManualClock(), poll_s=0.125, profile=PROFILE)
    return server, table


def test_counts_per_rev_and_limits_come_from_the_profile():
    server, table = make([])
    assert table.counts_per_rev() == 1 << 22
    assert table.max_rate_dps() == 600.0 and table.max_accel_dps2() == 1500.0
    with pytest.raises(ValueError, match="600"):
        table.set_rate(700.0)
    finish(server, table)


def test_identify_reads_the_profiles_string_block():
    regs = str_regs("Kollmorgen AKD2G", 10) + str_regs("AKD-17", 6) + str_regs("02-04", 4)
    server, table = make([Pair(read_pdu(1300, 20), read_reply(regs))])
    ident = table.identify()
    assert (ident.manufacturer, ident.model, ident.serial, ident.firmware) == (
        "Kollmorgen", "Kollmorgen AKD2G", "AKD-17", "02-04"
    )
    finish(server, table)


def test_status_decodes_low_word_first_with_the_profiles_scales_and_bits():
    server, table = make([
        status_read(bits=READY | ENABLED | AT_RATE | MOVING, t_ms=0xFFFF_FFF0,
                    pos_e4=-1_234_567, rate_e2=-10_025, counts=-5),
        status_read(t_ms=0x10, counts=3),
    ])
    s = table.read_status()
    assert s.ready and s.enabled and s.at_rate and s.moving
    assert not (s.fault or s.in_position or s.interlock_open)
    assert s.position_deg == pytest.approx(-123.4567) and s.rate_dps == pytest.approx(-100.25)
    assert s.encoder_counts == (1 << 32) - 5
    s2 = table.read_status()
    assert s2.encoder_counts_unwrapped - s.encoder_counts_unwrapped == 8
    assert s2.controller_time_s - s.controller_time_s == pytest.approx(0.032)
    assert s2.controller_time_resolution_s == 1e-3  # this profile's clock counts ms
    finish(server, table)


def test_set_rate_writes_the_command_span_in_one_request_keeping_the_gap_register():
    before = cmd_regs(mode=8, pos_e4=900_000, accel_e1=2000, move_e2=350)
    after = cmd_regs(mode=3, pos_e4=900_000, rate_e2=-15_050, accel_e1=500, move_e2=350)
    server, table = make([
        Pair(read_pdu(1100, 9), read_reply(before)),
        Pair(write_many_pdu(1100, after), write_many_reply(1100, 9)),
        status_read(),
    ])
    table.set_rate(-150.5, accel_dps2=50.0)
    finish(server, table)


def test_move_to_with_move_time_in_the_profiles_units():
    before = cmd_regs(mode=3, rate_e2=1000)
    after = cmd_regs(mode=8, rate_e2=1000, pos_e4=-900_000, move_e2=350)
    server, table = make([
        Pair(read_pdu(1100, 9), read_reply(before)),
        Pair(write_many_pdu(1100, after), write_many_reply(1100, 9)),
        status_read(),
    ])
    table.move_to(-90.0, move_time_s=3.5)
    finish(server, table)


def test_enable_sets_the_profiles_enable_bit_dropping_edge_bits_and_halt():
    server, table = make([
        status_read(bits=READY),
        Pair(read_pdu(1000, 1), read_reply([HALT | FAULT_RESET | ZERO | 0x0003])),
        Pair(write_pdu(1000, ENABLE), write_pdu(1000, ENABLE)),
        status_read(bits=READY | ENABLED),
    ])
    table.enable()
    finish(server, table)


def test_interlock_bit_raises_interlock_open():
    server, table = make([status_read(bits=INTERLOCK)])
    with pytest.raises(InterlockOpen):
        table.enable()
    finish(server, table)


def test_fault_code_text_comes_from_the_profile():
    server, table = make([status_read(bits=FAULT, fault=0x68)])
    with pytest.raises(TableFault, match="F68 STO") as info:
        table.check()
    assert info.value.fault_code == 0x68
    finish(server, table)


def test_refused_command_raises_instrument_error():
    server, table = make([
        Pair(read_pdu(1100, 9), read_reply(cmd_regs())),
        Pair(write_many_pdu(1100, cmd_regs(mode=8, pos_e4=100_000, accel_e1=90_000)),
                 exception_reply(16, 3)),
    ])
    with pytest.raises(InstrumentError, match="refused.*9000"):
        table.move_to(10.0, accel_dps2=9000.0)
    finish(server, table)
