"""Table and chamber twins over real Modbus TCP; supply and fixture over real ptys."""

import time

import pytest
import serial
from pymodbus.client import ModbusTcpClient

from drivers import chamber_map as cm
from drivers.fixture_protocol import FrameParser
from drivers.rate_table_map import COUNTS_PER_REV, Control, Mode, Reg, Status
from drivers.sim.launcher import BenchHandle
from drivers.sim.stream_probe import scpi

from .conftest import i32, modbus_client, regs32, u32, wait_until

DEV = {"device_id": 1}


@pytest.fixture(scope="module")
def table(bench: BenchHandle) -> ModbusTcpClient:
    client = modbus_client(bench.endpoints.rate_table)
    yield client
    client.close()


def _status(client: ModbusTcpClient) -> int:
    return client.read_holding_registers(Reg.STATUS, count=1, **DEV).registers[0]


def _snapshot(client: ModbusTcpClient) -> tuple[int, float, int]:
    r = client.read_holding_registers(22, count=8, **DEV).registers
    return u32(r[0], r[1]), u32(r[6], r[7]) * 1e-6, i32(r[2], r[3])


def _stop(client: ModbusTcpClient, speed: float) -> None:
    client.write_register(Reg.MODE, Mode.IDLE, **DEV)
    wait_until(lambda: not _status(client) & Status.MOVING, 60 / speed + 5, "the table at rest")


def test_rate_mode_100dps_encoder_mean_rate_within_001_percent(
    table: ModbusTcpClient, bench: BenchHandle
) -> None:
    assert not table.write_register(Reg.CONTROL, Control.ENABLE, **DEV).isError()
    table.write_registers(Reg.RATE_CMD, regs32(100_000), **DEV)
    table.write_register(Reg.MODE, Mode.RATE, **DEV)
    wait_until(lambda: bool(_status(table) & Status.AT_RATE), 5 / bench.speed + 5, "AT_RATE")
    c1, t1, _ = _snapshot(table)
    time.sleep(10.2 / bench.speed)
    c2, t2, _ = _snapshot(table)
    dt = t2 - t1
    assert dt >= 10.0
    rate = ((c2 - c1) % (1 << 32)) * 360.0 / COUNTS_PER_REV / dt
    assert abs(rate - 100.0) / 100.0 < 1e-4, rate
    truth = bench.control.truth()["table"]
    assert truth["mode"] == "rate" and abs(truth["rate_dps"] - 100) < 0.01
    _stop(table, bench.speed)


def test_position_move_90deg_in_3p5s_ends_within_one_count(
    table: ModbusTcpClient, bench: BenchHandle
) -> None:
    table.write_register(Reg.CONTROL, Control.ENABLE | Control.ZERO_ENCODER, **DEV)
    assert _snapshot(table)[0] in (0, 1, (1 << 32) - 1)
    table.write_registers(Reg.MOVE_TIME, regs32(3500), **DEV)
    table.write_registers(Reg.POS_CMD, regs32(90_000), **DEV)
    t0 = bench.control.world_time_s()
    table.write_register(Reg.MODE, Mode.POSITION, **DEV)
    time.sleep(1.0 / bench.speed)
    assert _status(table) & Status.MOVING
    wait_until(
        lambda: bool(_status(table) & Status.IN_POSITION), 10 / bench.speed + 5, "IN_POSITION"
    )
    elapsed = bench.control.world_time_s() - t0
    # 3.5 s move plus the configured bounce settling (0.15 s * ln(0.02 / 0.0005) = 0.55 s)
    assert 3.5 <= elapsed < 3.5 + 0.6 + 0.3 + 0.05 * bench.speed
    counts, _, pos_mdeg = _snapshot(table)
    assert abs(i32(counts >> 16, counts & 0xFFFF) - COUNTS_PER_REV // 4) <= 1
    assert abs(pos_mdeg - 90_000) <= 1


def test_table_refuses_writes_to_read_only_and_bad_values(table: ModbusTcpClient) -> None:
    r = table.write_registers(Reg.ENCODER_COUNTS, [0, 0], **DEV)
    assert r.isError() and r.exception_code == 2
    r = table.write_registers(Reg.RATE_CMD, regs32(5_000_000), **DEV)
    assert r.isError() and r.exception_code == 3
    r = table.read_holding_registers(200, count=2, **DEV)
    assert r.isError()


def test_table_identity_strings(table: ModbusTcpClient) -> None:
    regs = table.read_holding_registers(Reg.SERIAL, count=12, **DEV).registers
    text = b"".join(r.to_bytes(2, "big") for r in regs)
    assert text[:16].rstrip(b"\0") == b"RT-0001" and text[16:].rstrip(b"\0") == b"2.4.1"


def test_chamber_limits_setpoint_and_air_response(bench: BenchHandle) -> None:
    client = modbus_client(bench.endpoints.chamber)
    try:
        lo, hi = client.read_holding_registers(cm.Reg.SP_LIMIT_LOW, count=2, **DEV).registers
        assert (lo, hi) == (0x10000 - 400, 1250)
        r = client.write_register(cm.Reg.SETPOINT, 2000, **DEV)
        assert r.isError() and r.exception_code == 3
        r = client.write_register(cm.Reg.PROCESS_VALUE, 10, **DEV)
        assert r.isError() and r.exception_code == 2
        pv0 = client.read_holding_registers(cm.Reg.PROCESS_VALUE, count=1, **DEV).registers[0]
        client.write_register(cm.Reg.SETPOINT, 350, **DEV)
        client.write_register(cm.Reg.RAMP_RATE, 0, **DEV)
        client.write_register(cm.Reg.RUN, 1, **DEV)
        # 10 C at 5 C/min with a 60 s air lag: at setpoint after about 3-4 min of world time
        time.sleep(60 / bench.speed)
        state = client.read_holding_registers(cm.Reg.STATE, count=1, **DEV).registers[0]
        pv1 = client.read_holding_registers(cm.Reg.PROCESS_VALUE, count=1, **DEV).registers[0]
        assert state == cm.State.RAMPING and pv0 < pv1 < 350
        wait_until(
            lambda: (
                client.read_holding_registers(cm.Reg.STATE, count=1, **DEV).registers[0]
                == cm.State.AT_SETPOINT
            ),
            600 / bench.speed + 5,
            "chamber at setpoint",
        )
        elapsed_min = bench.control.world_time_s() / 60
        assert elapsed_min > 2.0
        client.write_register(cm.Reg.SETPOINT, 250, **DEV)
        client.write_register(cm.Reg.RUN, 0, **DEV)
        assert bench.control.truth()["chamber"]["running"] is False
    finally:
        client.close()


def test_supply_scpi_over_pty(bench: BenchHandle) -> None:
    sup = bench.endpoints.supply
    scpi(sup, "*RST")
    replies = scpi(
        sup,
        "VOLT 5.25",
        "CURR 0.2",
        "OUTP ON",
        "OUTP?",
        "MEAS:VOLT?",
        "MEAS:CURR?",
        "VOLT 100",
        "NONSENSE",
        "SYST:ERR?",
        "SYST:ERR?",
        "SYST:ERR?",
    )
    assert replies[0] == "1"
    assert float(replies[1]) == pytest.approx(5.25, abs=0.002)
    # two parts drawing 20-30 mA each at 5 V, a little more at 5.25 V
    assert 0.04 < float(replies[2]) < 0.065
    assert replies[3].startswith("-222") and replies[4].startswith("-113")
    assert replies[5] == '+0,"No error"'
    truth = bench.control.truth()
    assert truth["supply"]["mode"] == "CV"
    assert truth["sockets"]["1"]["powered"] and truth["sockets"]["2"]["powered"]
    scpi(sup, "OUTP OFF")
    assert bench.control.truth()["sockets"]["1"]["powered"] is False


def test_fixture_commands_over_pty(bench: BenchHandle) -> None:
    scpi(bench.endpoints.supply, "VOLT 5.0", "CURR 0.5", "OUTP ON")
    parser = FrameParser()
    with serial.Serial(bench.endpoints.duts[1], timeout=0.05) as port:

        def ask(line: str) -> str:
            port.write(line.encode() + b"\n")
            deadline = time.monotonic() + 3
            while time.monotonic() < deadline:
                res = parser.feed(port.read(4096))
                if res.replies:
                    return res.replies[0]
            raise AssertionError(f"no reply to {line}")

        assert ask("IDN?").startswith("OK SIMFIX,")
        assert ask("PRESENT?") == "OK 1"
        assert ask("SN?") == "OK SIM-T001"
        assert ask("STOPANGLE?").startswith("OK 9")
        assert ask("ODR 333").startswith("ERR 3")
        assert ask("FLY").startswith("ERR 2")
        assert ask("CAL scale=1.0567 bias=8.6") == "OK"
        assert ask("CAL wrong=1").startswith("ERR 4")
        cal = dict(kv.split("=") for kv in ask("CAL?")[3:].split())
        assert float(cal["scale"]) == 1.0567 and float(cal["bias"]) == 8.6
        assert bench.control.truth()["sockets"]["1"]["calibration"]["bias_dps"] == 8.6
        assert ask("COMP 1") == "OK"
        assert ask("ODR 1000") == "OK"
        assert ask("START") == "OK"
        assert ask("ODR 200").startswith("ERR 5")
        time.sleep(0.05)
        assert ask("STOP") == "OK"
        assert parser.frames_ok > 10 and parser.frames_lost == 0
        assert ask("COMP 0") == "OK"
        assert ask("CAL bias=0 scale=1") == "OK"
