"""Safe-state readback, reconnect and watchdog methods of the drivers: exact requests on the
wire (scripted Modbus server, scripted serial port), typed exceptions."""

from __future__ import annotations

import pytest

from drivers.chamber import ModbusChamber
from drivers.errors import ChamberFault, ControllerHung, InterlockOpen, TableFault
from drivers.modbus_link import ModbusLink
from drivers.protocols import ChamberReadsBackSafe, ReadsBackSafe, Reconnectable, Watched
from drivers.rate_table import ModbusRateTable
from drivers.rate_table_map import Fault, Status
from drivers.supply import ScpiSupply
from tests.drivers._fakes import (
    ManualClock,
    pair,
    read_pdu,
    read_reply,
)
from tests.drivers._scpi_fakes import ScriptedScpi
from tests.drivers.expected_protocol import MODBUS, Pair, TcpPeer, finish


def table_regs(
    bits: Status, fault: int = 0, rate_mdps: int = 0, beat: int | None = None
) -> list[int]:
    regs = [int(bits), fault, *pair(0), *pair(0), *pair(rate_mdps), *pair(0)]
    return regs if beat is None else [*regs, beat]


def make_table(script: list[Pair], clock: ManualClock | None = None):
    server = TcpPeer(script, MODBUS)
    link = ModbusLink("127.0.0.1", server.port, timeout_s=0.5, instrument="rate table")
    return server, ModbusRateTable(link, clock or ManualClock())


def test_drivers_implement_the_readback_protocols() -> None:
    server, table = make_table([])
    assert isinstance(table, ReadsBackSafe) and isinstance(table, Reconnectable)
    assert isinstance(table, Watched)
    finish(server, table)
    link = ModbusLink("127.0.0.1", 1, instrument="chamber")
    assert isinstance(ModbusChamber(link, ManualClock()), ChamberReadsBackSafe)
    assert hasattr(ScpiSupply, "check_safe")
    assert issubclass(ScpiSupply, ReadsBackSafe)


@pytest.mark.parametrize(
    ("bits", "rate_mdps", "safe", "words"),
    [
        (Status.READY, 0, True, "disabled"),
        (Status.READY | Status.ENABLED, 0, False, "enabled"),
        (Status.READY | Status.MOVING, -50_000, False, "still moving"),
    ],
)
def test_table_check_safe_reads_status_once(bits, rate_mdps, safe, words) -> None:
    server, table = make_table(
        [Pair(read_pdu(20, 10), read_reply(table_regs(bits, rate_mdps=rate_mdps)))]
    )
    readback = table.check_safe()
    assert readback.safe is safe and words in readback.detail
    finish(server, table)


def test_table_watchdog_reads_status_and_heartbeat_in_one_request() -> None:
    clock = ManualClock()
    ok = Status.READY
    server, table = make_table(
        [
            Pair(read_pdu(20, 11), read_reply(table_regs(ok, beat=100))),
            Pair(read_pdu(20, 11), read_reply(table_regs(ok, beat=300))),
        ],
        clock,
    )
    table.watchdog_check()
    clock.sleep_s(2.0)
    table.watchdog_check()
    finish(server, table)


def test_table_watchdog_raises_on_estop_at_rest() -> None:
    # one request: the fault is judged from the same block as the heartbeat
    estop = table_regs(Status.FAULT, fault=int(Fault.ESTOP))
    server, table = make_table(
        [
            Pair(read_pdu(20, 11), read_reply([*estop, 5])),
        ]
    )
    with pytest.raises(TableFault, match="emergency stop"):
        table.watchdog_check()
    finish(server, table)


def test_table_watchdog_raises_on_open_interlock() -> None:
    regs = table_regs(Status.INTERLOCK_OPEN)
    server, table = make_table(
        [
            Pair(read_pdu(20, 11), read_reply([*regs, 5])),
        ]
    )
    with pytest.raises(InterlockOpen, match="interlock"):
        table.watchdog_check()
    finish(server, table)


def test_table_watchdog_raises_when_the_heartbeat_stops() -> None:
    clock = ManualClock()
    ok = Status.READY
    server, table = make_table(
        [Pair(read_pdu(20, 11), read_reply(table_regs(ok, beat=7))) for _ in range(3)],
        clock,
    )
    table.watchdog_check()
    clock.sleep_s(0.5)
    table.watchdog_check()  # unchanged, but too soon to judge
    clock.sleep_s(1.0)
    with pytest.raises(ControllerHung, match="heartbeat"):
        table.watchdog_check()
    finish(server, table)


def make_chamber(script: list[Pair]):
    server = TcpPeer(script, MODBUS)
    link = ModbusLink("127.0.0.1", server.port, timeout_s=0.5, instrument="thermal chamber")
    return server, ModbusChamber(link, ManualClock())


@pytest.mark.parametrize(("setpoint_tenths", "safe"), [(250, True), (450, False)])
def test_chamber_check_safe_reads_setpoint_against_the_safe_temperature(
    setpoint_tenths: int, safe: bool
) -> None:
    server, chamber = make_chamber(
        [
            Pair(read_pdu(602, 2), read_reply([(-400) & 0xFFFF, 1250])),
            Pair(read_pdu(300, 1), read_reply([setpoint_tenths])),
            Pair(read_pdu(100, 1), read_reply([300])),
            Pair(read_pdu(1000, 1), read_reply([1])),
        ]
    )
    readback = chamber.check_safe(25.0)
    assert readback.safe is safe
    assert f"setpoint {setpoint_tenths / 10:g} C" in readback.detail
    assert "running" in readback.detail
    finish(server, chamber)


def test_chamber_watchdog_raises_on_fault_state() -> None:
    server, chamber = make_chamber(
        [
            Pair(read_pdu(200, 1), read_reply([3])),
            Pair(read_pdu(100, 1), read_reply([412])),
            Pair(read_pdu(300, 1), read_reply([450])),
        ]
    )
    with pytest.raises(ChamberFault, match="reports a fault at 41.2 C"):
        chamber.watchdog_check()
    finish(server, chamber)


def test_chamber_watchdog_quiet_while_ramping() -> None:
    server, chamber = make_chamber([Pair(read_pdu(200, 1), read_reply([1]))])
    chamber.watchdog_check()
    finish(server, chamber)


@pytest.mark.parametrize(("reply", "safe"), [(b"0\n", True), (b"1\n", False)])
def test_supply_check_safe_asks_outp(reply: bytes, safe: bool) -> None:
    script = [Pair(b"OUTP?\n", reply)]
    if not safe:
        script.append(Pair(b"MEAS:VOLT?\n", b"5.000\n"))
    fake = ScriptedScpi(script)
    supply = ScpiSupply.open(fake.resource, timeout_s=0.5)
    readback = supply.check_safe()
    supply.close()
    assert readback.safe is safe
    fake.assert_done()
