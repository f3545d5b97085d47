"""Both rate-table families against their twins over real sockets (speed 100): the encoder
reference, moves, and every fault surfacing as its documented typed exception: lost
connection, late replies, error replies, e-stop and other table faults, the safety interlock.

Families: `acutrol` (AcutrolTwin), `modbus-servo` with today's map (TableTwin, no profile)
and with the low-word-first example profile (TableTwin serving that profile)."""

from __future__ import annotations

import time
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import pytest

from common.clock import ScaledClock
from drivers import acutrol, rate_table
from drivers.errors import (
    ConnectionLost,
    InstrumentError,
    InstrumentTimeout,
    InterlockOpen,
    SetpointOutOfRange,
    TableFault,
)
from drivers.protocols import RateTable
from drivers.rate_table_map import Fault
from drivers.sim.acutrol_twin import AcutrolTwin
from drivers.sim.modbus_twins import TableTwin
from tests.drivers._twin_thread import TwinThread

SPEED = 100.0
EXAMPLE = "servo-lowword-example"


@dataclass(frozen=True)
class Family:
    name: str
    make_twin: Any
    factory: Any
    settings: dict[str, Any]
    config: dict[str, Any]
    estop_code: int
    estop_text: str

    def endpoint(self, twin: Any) -> str:
        return twin.endpoint() if callable(twin.endpoint) else twin.endpoint


FAMILIES = [
    Family("acutrol", AcutrolTwin, acutrol.factory, {}, {}, 4, "emergency stop"),
    Family("modbus-servo", TableTwin, rate_table.factory, {}, {}, 4, "emergency stop"),
    Family(
        "modbus-servo+example", lambda w: TableTwin(w, profile=EXAMPLE), rate_table.factory,
        {"profile": EXAMPLE}, {"table": {"counts_per_rev": 1 << 22}}, 0x68, "F68 STO",
    ),
]


@dataclass
class Rig:
    family: Family
    twin: TwinThread
    table: Any

    def world_time_s(self) -> float:
        return float(self.twin.call(self.twin.world.advance))


@pytest.fixture(params=FAMILIES, ids=lambda f: f.name)
def rig(request: pytest.FixtureRequest) -> Iterator[Rig]:
    family: Family = request.param
    with TwinThread(family.make_twin, speed=SPEED, config=family.config) as tt:
        settings = {"address": family.endpoint(tt.twin), "timeout_s": 0.5, **family.settings}
        table = family.factory(settings)
        table.attach_clock(ScaledClock(SPEED))
        try:
            yield Rig(family, tt, table)
        finally:
            table.close()


def test_driver_implements_the_protocol_and_counts_per_rev_of_its_encoder(rig: Rig):
    assert isinstance(rig.table, RateTable)
    assert rig.table.counts_per_rev() == rig.twin.world.table.cpr
    assert rig.table.identify().model == "SIM-RT-360"


def test_encoder_reference_rate_and_a_timed_move(rig: Rig):
    table = rig.table
    table.reset_fault()
    table.enable()
    table.set_rate(-50.0, accel_dps2=500.0)
    table.wait_at_rate(30.0)
    s1 = table.read_status()
    time.sleep(0.05)
    s2 = table.read_status()
    counts = s2.encoder_counts_unwrapped - s1.encoder_counts_unwrapped
    rate = counts * 360.0 / table.counts_per_rev() / (s2.controller_time_s - s1.controller_time_s)
    assert rate == pytest.approx(-50.0, rel=1e-3)
    table.set_rate(0.0, accel_dps2=500.0)
    start = table.wait_at_rate(30.0)
    t0 = rig.world_time_s()
    table.move_to(start.position_deg + 90.0, move_time_s=2.0)
    end = table.wait_in_position(30.0)
    assert rig.world_time_s() - t0 >= 2.0
    assert end.position_deg - start.position_deg == pytest.approx(90.0, abs=0.002)
    truth = rig.twin.call(rig.twin.world.truth)["table"]
    assert truth["rate_dps"] == pytest.approx(0.0, abs=1e-3)


def test_lost_connection_raises_connection_lost_and_restore_serves_again(rig: Rig):
    assert rig.table.read_status().ready
    rig.twin.run(rig.twin.twin.drop())
    t0 = time.monotonic()
    with pytest.raises(ConnectionLost):
        rig.table.read_status()
    with pytest.raises(ConnectionLost):  # refused while dropped, not a hang
        rig.table.read_status()
    assert time.monotonic() - t0 < 2 * 0.5 + 0.5
    rig.twin.run(rig.twin.twin.restore())
    assert rig.table.read_status().ready


def test_late_replies_raise_instrument_timeout_and_the_link_recovers(rig: Rig):
    rig.twin.twin.delay_s = 0.8
    with pytest.raises(InstrumentTimeout):
        rig.table.read_status()
    rig.twin.twin.delay_s = 0.0
    time.sleep(0.9)
    assert rig.table.read_status().ready


def test_a_value_beyond_the_tables_limit_is_an_error_reply_raised_typed(rig: Rig):
    rig.table.reset_fault()
    rig.table.enable()
    with pytest.raises(InstrumentError, match="refused") as info:
        rig.table.set_rate(10.0, accel_dps2=5000.0)  # the table's maximum is 2000 (1500)
    if rig.family.name == "acutrol":
        assert isinstance(info.value, SetpointOutOfRange)


def test_estop_raises_table_fault_until_released_and_reset(rig: Rig):
    table = rig.table
    table.reset_fault()
    table.enable()
    table.set_rate(200.0, accel_dps2=10.0)  # a 20 s ramp: the wait is still running
    rig.twin.call(lambda: rig.twin.world.trip_table(Fault.ESTOP))
    with pytest.raises(TableFault, match=rig.family.estop_text) as info:
        table.wait_at_rate(60.0)
    assert info.value.fault_code == rig.family.estop_code
    assert not isinstance(info.value, InterlockOpen)
    with pytest.raises(TableFault):
        table.reset_fault()  # the e-stop is still pressed
    with pytest.raises(TableFault):
        table.enable()
    rig.twin.call(rig.twin.world.clear_world_faults)
    table.reset_fault()
    table.enable()
    assert table.read_status().enabled


@pytest.mark.parametrize("fault", [Fault.FOLLOWING_ERROR, Fault.ENCODER_LOSS, Fault.OVERSPEED])
def test_other_table_faults_raise_table_fault_and_reset_clears_them(rig: Rig, fault: Fault):
    table = rig.table
    table.reset_fault()
    table.enable()
    rig.twin.call(lambda: rig.twin.world.trip_table(fault))
    with pytest.raises(TableFault) as info:
        table.set_rate(10.0)
    assert info.value.fault_code != 0
    table.reset_fault()
    table.enable()


def test_interlock_open_raises_interlock_open_while_moving_and_on_enable(rig: Rig):
    table = rig.table
    table.reset_fault()
    table.enable()
    table.set_rate(100.0, accel_dps2=10.0)
    rig.twin.call(lambda: rig.twin.world.set_interlock(True))
    with pytest.raises(InterlockOpen, match="interlock is open"):
        table.wait_at_rate(30.0)
    with pytest.raises(InterlockOpen):
        table.enable()
    rig.twin.call(rig.twin.world.clear_world_faults)
    table.reset_fault()
    table.enable()


def test_safe_state_stops_and_disables_and_is_quiet_when_safe(rig: Rig):
    table = rig.table
    table.reset_fault()
    table.enable()
    table.set_rate(100.0, accel_dps2=500.0)
    table.wait_at_rate(30.0)
    table.safe_state()
    truth = rig.twin.call(rig.twin.world.truth)["table"]
    assert not truth["enabled"] and truth["rate_dps"] == 0.0
    table.safe_state()
