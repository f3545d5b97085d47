"""The world's instrument models on their own (no sockets): table, chamber, supply."""

import numpy as np
import pytest

from drivers.rate_table_map import Control, Fault, Mode, Reg, Status
from drivers.sim.chamber import ChamberModel
from drivers.sim.config import ChamberConfig, SupplyConfig, TableConfig
from drivers.sim.supply import SupplyModel
from drivers.sim.table import CommandRefusedError, TableModel

from .conftest import i32, regs32


def _write(table: TableModel, t: float, first: int, values: list[int]) -> None:
    table.write(t, first, values, table.registers(t))


def test_table_rate_mode_and_status_bits() -> None:
    table = TableModel(TableConfig(ripple_dps=0.0))
    _write(table, 0.0, Reg.CONTROL, [int(Control.ENABLE)])
    _write(table, 0.0, Reg.RATE_CMD, regs32(50_000))
    _write(table, 0.0, Reg.MODE, [int(Mode.RATE)])
    assert table.status_bits(0.1) & Status.MOVING
    assert not table.status_bits(0.1) & Status.AT_RATE  # still ramping at 100 deg/s^2
    regs = table.registers(5.0)
    assert regs[Reg.STATUS] & Status.AT_RATE
    assert i32(*regs[Reg.RATE_FB : Reg.RATE_FB + 2]) == 50_000
    # 0.5 s ramp covers 12.5 deg, then 4.5 s at 50 deg/s
    assert i32(*regs[Reg.POS_FB : Reg.POS_FB + 2]) == pytest.approx(237_500, abs=1)


def test_table_refuses_bad_values_and_keeps_state() -> None:
    table = TableModel(TableConfig())
    with pytest.raises(CommandRefusedError):
        _write(table, 0.0, Reg.RATE_CMD, regs32(2_000_000))
    with pytest.raises(CommandRefusedError):
        _write(table, 0.0, Reg.ACCEL_LIMIT, regs32(0))
    with pytest.raises(CommandRefusedError):
        _write(table, 0.0, Reg.MODE, [7])
    assert table.rate_cmd_mdps == 0 and table.accel_mdps2 == 100_000


def test_table_fault_reset_and_estop_latch() -> None:
    table = TableModel(TableConfig())
    _write(table, 0.0, Reg.CONTROL, [int(Control.ENABLE)])
    _write(table, 0.0, Reg.RATE_CMD, regs32(100_000))
    _write(table, 0.0, Reg.MODE, [int(Mode.RATE)])
    table.inject_fault(3.0, Fault.FOLLOWING_ERROR)
    regs = table.registers(3.01)
    assert regs[Reg.FAULT_CODE] == Fault.FOLLOWING_ERROR
    assert regs[Reg.STATUS] & Status.FAULT and not regs[Reg.STATUS] & Status.ENABLED
    assert table.is_safe(4.0)  # stopped at the maximum deceleration
    _write(table, 4.0, Reg.CONTROL, [int(Control.FAULT_RESET | Control.ENABLE)])
    assert table.fault == Fault.NONE and table.enabled
    table.inject_fault(5.0, Fault.ESTOP)
    _write(table, 6.0, Reg.CONTROL, [int(Control.FAULT_RESET)])
    assert table.fault == Fault.ESTOP  # e-stop still pressed
    table.clear_faults()
    _write(table, 6.0, Reg.CONTROL, [int(Control.FAULT_RESET)])
    assert table.fault == Fault.NONE


def test_table_interlock_refuses_enable() -> None:
    table = TableModel(TableConfig())
    table.set_interlock(0.0, True)
    _write(table, 0.0, Reg.CONTROL, [int(Control.ENABLE)])
    regs = table.registers(0.0)
    assert regs[Reg.STATUS] & Status.INTERLOCK_OPEN
    assert not regs[Reg.STATUS] & (Status.ENABLED | Status.READY)


def test_table_zero_encoder_and_position_move() -> None:
    table = TableModel(TableConfig(ripple_dps=0.0))
    _write(table, 0.0, Reg.CONTROL, [int(Control.ENABLE)])
    _write(table, 0.0, Reg.RATE_CMD, regs32(10_000))
    _write(table, 0.0, Reg.MODE, [int(Mode.RATE)])
    _write(table, 3.0, Reg.MODE, [int(Mode.IDLE)])
    _write(table, 4.0, Reg.CONTROL, [int(Control.ENABLE | Control.ZERO_ENCODER)])
    assert i32(*table.registers(4.0)[Reg.ENCODER_COUNTS : Reg.ENCODER_COUNTS + 2]) == 0
    _write(table, 4.0, Reg.MOVE_TIME, regs32(3500))
    _write(table, 4.0, Reg.POS_CMD, regs32(-45_000))
    _write(table, 4.0, Reg.MODE, [int(Mode.POSITION)])
    regs = table.registers(8.0)
    assert regs[Reg.STATUS] & Status.IN_POSITION
    counts = i32(*regs[Reg.ENCODER_COUNTS : Reg.ENCODER_COUNTS + 2])
    assert abs(counts - (-45 / 360 * table.cpr)) <= 1
    assert not table.registers(5.0)[Reg.STATUS] & Status.IN_POSITION


def test_chamber_ramp_limit_and_first_order_air() -> None:
    ch = ChamberModel(ChamberConfig(air_tau_s=60.0, max_ramp_c_per_min=5.0))
    ch.write(300, 850)  # 85.0 C
    ch.write(1001, 20)  # 2.0 C/min
    ch.write(1000, 1)
    for _ in range(600):
        ch.step(1.0)
    # the ramped setpoint moved 2 C/min for 10 min; the air lags by about rate * tau
    assert ch.ramped_sp_c == pytest.approx(45.0, abs=0.01)
    assert ch.air_c == pytest.approx(45.0 - 2.0 / 60 * 60, abs=0.2)
    assert ch.registers()[200] == 1  # ramping
    with pytest.raises(ValueError):
        ch.write(300, 2000)  # 200 C, beyond the high limit
    with pytest.raises(PermissionError):
        ch.write(100, 0)
    ch.stuck = True
    before = ch.air_c
    ch.step(600.0)
    assert ch.air_c == before


def test_supply_scpi_and_cv_cc_crossover() -> None:
    sup = SupplyModel(SupplyConfig(), np.random.default_rng(0))
    assert sup.handle("*IDN?").startswith("GYROCAL SIMULATED BENCH,SCPI SUPPLY TWIN,")
    for line in ("VOLT 5.0", "CURR 0.1", "OUTP ON"):
        assert sup.handle(line) is None
    sup.load_siemens = 0.005  # 25 mA at 5 V
    v, i, mode = sup.operating_point()
    assert (v, mode) == (5.0, "CV") and i == pytest.approx(0.025)
    assert float(sup.handle("MEAS:CURR?")) == pytest.approx(0.025, abs=1e-4)
    sup.load_siemens += 2.0  # a shorted part
    v, i, mode = sup.operating_point()
    assert mode == "CC" and i == pytest.approx(0.1) and v < 0.06
    sup.handle("VOLT 99")
    sup.handle("FOO")
    assert sup.handle("SYST:ERR?").startswith("-222")
    assert sup.handle("SYST:ERR?").startswith("-113")
    assert sup.handle("SYST:ERR?") == '+0,"No error"'
    assert sup.voltage_set_v == 5.0
    sup.handle("*RST")
    assert sup.handle("OUTP?") == "0"
