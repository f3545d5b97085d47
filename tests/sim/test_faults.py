"""Faults injected through the control channel, each visible on the wire."""

import time
from collections.abc import Iterator

import pytest
from pymodbus.exceptions import ModbusException

from drivers import chamber_map as cm
from drivers.rate_table_map import Control, Fault, Mode, Reg, Status
from drivers.sim.control_client import ControlError
from drivers.sim.launcher import BenchHandle, launch_bench
from drivers.sim.stream_probe import StreamProbe, power_parts, scpi

from .conftest import TWO_PARTS, modbus_client, regs32

DEV = {"device_id": 1}


@pytest.fixture(scope="module")
def fbench() -> Iterator[BenchHandle]:
    with launch_bench(config=TWO_PARTS, speed=100) as handle:
        yield handle


@pytest.fixture(autouse=True)
def _clear(fbench: BenchHandle) -> Iterator[None]:
    yield
    fbench.control.clear_faults()


def test_modbus_drop_refuses_connections_until_cleared(fbench: BenchHandle) -> None:
    client = modbus_client(fbench.endpoints.rate_table)
    assert not client.read_holding_registers(Reg.STATUS, count=1, **DEV).isError()
    fbench.control.fault("modbus_drop", target="table")
    with pytest.raises((ModbusException, ConnectionError)):
        r = client.read_holding_registers(Reg.STATUS, count=1, **DEV)
        assert not r.isError()
    client.close()
    with pytest.raises(AssertionError, match="cannot connect"):
        modbus_client(fbench.endpoints.rate_table, timeout_s=0.5)
    # the chamber is not affected
    chamber = modbus_client(fbench.endpoints.chamber)
    assert not chamber.read_holding_registers(cm.Reg.PROCESS_VALUE, count=1, **DEV).isError()
    chamber.close()
    fbench.control.clear_faults()
    client = modbus_client(fbench.endpoints.rate_table)
    assert not client.read_holding_registers(Reg.STATUS, count=1, **DEV).isError()
    client.close()


def test_modbus_delay_answers_past_the_timeout(fbench: BenchHandle) -> None:
    fbench.control.fault("modbus_delay", target="chamber", delay_s=1.5)
    client = modbus_client(fbench.endpoints.chamber, timeout_s=0.3)
    t0 = time.monotonic()
    with pytest.raises(ModbusException):
        r = client.read_holding_registers(cm.Reg.PROCESS_VALUE, count=1, **DEV)
        assert not r.isError()
    assert time.monotonic() - t0 < 1.4
    client.close()
    assert fbench.control.truth()["modbus"]["chamber"]["delay_s"] == 1.5


def _table_regs(fbench: BenchHandle) -> list[int]:
    client = modbus_client(fbench.endpoints.rate_table)
    try:
        return client.read_holding_registers(0, count=32, **DEV).registers
    finally:
        client.close()


def _write(fbench: BenchHandle, reg: int, values: list[int]) -> None:
    client = modbus_client(fbench.endpoints.rate_table)
    try:
        assert not client.write_registers(reg, values, **DEV).isError()
    finally:
        client.close()


@pytest.mark.parametrize(
    ("code", "fault"), [("following_error", Fault.FOLLOWING_ERROR), ("estop", Fault.ESTOP)]
)
def test_table_fault_stops_and_latches(fbench: BenchHandle, code: str, fault: Fault) -> None:
    _write(fbench, Reg.CONTROL, [Control.ENABLE | Control.FAULT_RESET])
    _write(fbench, Reg.RATE_CMD, regs32(50_000))
    _write(fbench, Reg.MODE, [Mode.RATE])
    fbench.control.fault("table_fault", code=code)
    regs = _table_regs(fbench)
    assert regs[Reg.STATUS] & Status.FAULT and regs[Reg.FAULT_CODE] == fault
    assert not regs[Reg.STATUS] & Status.ENABLED
    _write(fbench, Reg.CONTROL, [Control.FAULT_RESET])
    still = _table_regs(fbench)[Reg.FAULT_CODE]
    assert still == (fault if fault == Fault.ESTOP else Fault.NONE)
    fbench.control.clear_faults()
    _write(fbench, Reg.CONTROL, [Control.FAULT_RESET])
    assert _table_regs(fbench)[Reg.FAULT_CODE] == Fault.NONE
    time.sleep(3 / fbench.speed)  # the maximum deceleration stops 50 deg/s in 25 ms
    assert fbench.control.truth()["safe"]["table_stopped_and_disabled"]


def test_interlock_open_refuses_enable(fbench: BenchHandle) -> None:
    fbench.control.fault("interlock_open")
    _write(fbench, Reg.CONTROL, [Control.ENABLE])
    regs = _table_regs(fbench)
    assert regs[Reg.STATUS] & Status.INTERLOCK_OPEN
    assert not regs[Reg.STATUS] & (Status.ENABLED | Status.READY)
    fbench.control.clear_faults()
    _write(fbench, Reg.CONTROL, [Control.ENABLE])
    assert _table_regs(fbench)[Reg.STATUS] & Status.ENABLED
    _write(fbench, Reg.CONTROL, [0])


def test_chamber_stuck_never_reaches_setpoint(fbench: BenchHandle) -> None:
    fbench.control.fault("chamber_stuck", report_fault=True)
    client = modbus_client(fbench.endpoints.chamber)
    try:
        pv0 = client.read_holding_registers(cm.Reg.PROCESS_VALUE, count=1, **DEV).registers[0]
        client.write_register(cm.Reg.SETPOINT, 600, **DEV)
        client.write_register(cm.Reg.RUN, 1, **DEV)
        time.sleep(120 / fbench.speed)
        pv1 = client.read_holding_registers(cm.Reg.PROCESS_VALUE, count=1, **DEV).registers[0]
        state = client.read_holding_registers(cm.Reg.STATE, count=1, **DEV).registers[0]
        assert pv1 == pv0 and state == cm.State.FAULT
        client.write_register(cm.Reg.SETPOINT, 250, **DEV)
        client.write_register(cm.Reg.RUN, 0, **DEV)
    finally:
        client.close()


def test_supply_short_goes_constant_current_and_parts_brown_out(fbench: BenchHandle) -> None:
    power_parts(fbench.endpoints.supply, 5.0, 0.3)
    with StreamProbe([fbench.endpoints.duts[1]]) as probe:
        assert probe.command(0, "START") == "OK"
        probe.wait_frames(0)
        fbench.control.fault("supply_short", socket=2)
        probe.drain()
        got = probe.counts[0].frames_ok
        time.sleep(0.1)
        probe.drain()
        assert got > 0 and probe.counts[0].frames_ok == got  # browned out: no more frames
        assert probe.command(0, "SN?").startswith("ERR 11")
        probe.command(0, "STOP")
    volts, amps = (float(x) for x in scpi(fbench.endpoints.supply, "MEAS:VOLT?", "MEAS:CURR?"))
    assert volts < 1.0 and amps == pytest.approx(0.3, abs=1e-3)
    truth = fbench.control.truth()
    assert truth["supply"]["mode"] == "CC"
    assert not truth["sockets"]["1"]["powered"] and truth["sockets"]["2"]["shorted"]
    fbench.control.clear_faults()
    assert fbench.control.truth()["supply"]["mode"] == "CV"
    scpi(fbench.endpoints.supply, "OUTP OFF")


def test_stream_drop_and_corruption_are_counted_exactly(fbench: BenchHandle) -> None:
    power_parts(fbench.endpoints.supply)
    fbench.control.fault("stream_drop", socket=1, frame_drop_rate=0.05)
    with StreamProbe([fbench.endpoints.duts[1]]) as probe:
        before = fbench.control.truth()["sockets"]["1"]
        probe.stream(1000, frames=5000)
        after = fbench.control.truth()["sockets"]["1"]
        c = probe.counts[0]
        dropped = after["frames_fault_dropped"] - before["frames_fault_dropped"]
        sent = after["frames_sent"] - before["frames_sent"]
        # the fixture counts from 0 at START; drops before the first or after the last
        # delivered frame leave no gap in the sequence, so no reader can count them
        assert c.first_seq is not None and c.last_seq is not None
        at_edges = c.first_seq + (sent - 1 - c.last_seq)
        assert dropped > 100 and c.frames_lost == dropped - at_edges and c.frames_corrupted == 0
        assert c.frames_ok + c.frames_lost + at_edges == sent
    fbench.control.clear_faults()
    fbench.control.fault("stream_corrupt", socket=1, byte_error_rate=1e-3)
    with StreamProbe([fbench.endpoints.duts[1]]) as probe:
        probe.stream(1000, frames=5000)
        c = probe.counts[0]
        assert c.frames_corrupted > 20 and c.frames_lost >= c.frames_corrupted
    assert fbench.control.truth()["sockets"]["1"]["bytes_corrupted"] > 20
    scpi(fbench.endpoints.supply, "OUTP OFF")


def test_part_silent_stops_the_stream_and_absent_part(fbench: BenchHandle) -> None:
    power_parts(fbench.endpoints.supply)
    with StreamProbe([fbench.endpoints.duts[1]]) as probe:
        assert probe.command(0, "START") == "OK"
        probe.wait_frames(0)
        fbench.control.fault("part_silent", socket=1)
        probe.drain()
        got = probe.counts[0].frames_ok
        assert got > 0
        time.sleep(0.1)  # 10 s of world time
        probe.drain()
        assert probe.counts[0].frames_ok == got
        assert fbench.control.truth()["sockets"]["1"]["streaming"] is False
        probe.command(0, "STOP")
        fbench.control.clear_faults()
        fbench.control.fault("part_absent", socket=1)
        assert probe.command(0, "PRESENT?") == "OK 0"
        assert probe.command(0, "SN?").startswith("ERR 10")
        fbench.control.clear_faults()
        fbench.control.fault("fixture_silent", socket=1)
        with pytest.raises(TimeoutError):
            probe.command(0, "IDN?", timeout_s=0.3)
    scpi(fbench.endpoints.supply, "OUTP OFF")


def test_control_channel_rejects_bad_requests_clearly(fbench: BenchHandle) -> None:
    ctl = fbench.control
    with pytest.raises(ControlError, match="unknown fault kind 'gremlins'"):
        ctl.fault("gremlins")
    with pytest.raises(ControlError, match="no socket 9"):
        ctl.fault("part_silent", socket=9)
    with pytest.raises(ControlError, match="unknown cmd"):
        ctl.request("dance")
    with pytest.raises(ControlError, match="frame_drop_rate must be between 0 and 1"):
        ctl.fault("stream_drop", socket=1, frame_drop_rate=3)
    with pytest.raises(ControlError, match="bad part: .*scale"):
        ctl.load(2, {"serial": "SIM-X", "scale": -1})


def test_load_unload_and_truth(fbench: BenchHandle) -> None:
    ctl = fbench.control
    res = ctl.load(2, {"serial": "SIM-LOADED", "bias_dps": 1.25})
    assert res["parameters"]["bias_dps"] == 1.25
    truth = ctl.truth()
    s2 = truth["sockets"]["2"]
    assert s2["serial"] == "SIM-LOADED" and s2["present"]
    assert set(truth) >= {"time_s", "speed", "table", "chamber", "supply", "sockets", "safe"}
    ctl.unload(2)
    assert ctl.truth()["sockets"]["2"]["present"] is False
    ctl.load(2, {"serial": "SIM-T002"})
