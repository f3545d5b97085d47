"""Clients that are not our drivers read the new chamber twins: mbpoll reads the F4T twin's
process value as a float at 2820, a plain TCP socket gets an answer to `TEMP?` from the ESPEC
twin; and each twin's protocol rules as a generic client sees them."""

from __future__ import annotations

import re
import socket
import struct
import subprocess

import pytest
from pymodbus.client import ModbusTcpClient

from drivers.sim.espec_twin import STUCK_ALARM_CODE, EspecP300Twin
from drivers.sim.watlow_f4t_twin import WatlowF4TTwin
from tests.drivers._chamber_twin_thread import TwinThread

AIR_C = 21.7  # an ambient no default produces, so the reads below are the world's


def _host_port(endpoint: str) -> tuple[str, int]:
    host, _, port = endpoint.rpartition(":")
    return host, int(port)


@pytest.mark.usefixtures("mbpoll")
def test_mbpoll_reads_the_f4t_process_value_as_a_float_at_2820() -> None:
    with TwinThread(WatlowF4TTwin, {"chamber": {"ambient_c": AIR_C}}) as tt:
        host, port = _host_port(tt.endpoint)
        # -0: 0-based references; 4:float in the default (low word first) order: no -B
        out = subprocess.run(
            ["mbpoll", "-m", "tcp", "-a", "1", "-0", "-1", "-r", "2820", "-c", "1",
             "-t", "4:float", "-p", str(port), host],
            capture_output=True, text=True, timeout=20,
        )
        assert out.returncode == 0, out.stderr
        values = dict(re.findall(r"^\[(\d+)\]:\s+(\S+)", out.stdout, re.MULTILINE))
        assert float(values["2820"]) == pytest.approx(AIR_C, abs=0.01)


def test_plain_socket_gets_an_answer_to_temp_from_the_espec_twin() -> None:
    config = {"chamber": {"ambient_c": AIR_C, "setpoint_low_c": -70.0, "setpoint_high_c": 180}}
    with TwinThread(EspecP300Twin, config) as tt, socket.create_connection(
        _host_port(tt.endpoint), timeout=5
    ) as sock:
        reader = sock.makefile("rb")
        sock.sendall(b"TEMP?\r\n")
        line = reader.readline()
        assert line.endswith(b"\r\n")
        pv, sp, upper, lower = (float(f) for f in line.decode().strip().split(","))
        assert (pv, sp, upper, lower) == (pytest.approx(AIR_C, abs=0.05), 25.0, 180.0, -70.0)
        for command, reply in (
            (b"TEMP, S40.0", b"OK:TEMP, S40.0"),
            (b"TEMP?", None),
            (b"TEMP, S190.0", b"NA:DATA OUT OF RANGE"),
            (b"FLY?", b"NA:CMD ERR"),
            (b"MODE, RUN1", b"NA:DATA NOT READY"),
            (b"MODE?", b"STANDBY"),
            (b"POWER,ON", b"OK:POWER,ON"),
            (b"MODE?", b"CONSTANT"),
            (b"MON?", None),
            (b"POWER,OFF", b"OK:POWER,OFF"),
            (b"MODE, CONSTANT", b"NA:CHB NOT READY"),
            (b"MODE?", b"OFF"),
        ):
            sock.sendall(command + b"\r\n")
            got = reader.readline().rstrip(b"\r\n")
            if reply is not None:
                assert got == reply, command
            elif command == b"TEMP?":
                assert got.split(b",")[1] == b"40.0"
            else:
                assert got.split(b",")[2:] == [b"CONSTANT", b"0"]
        assert not tt.world.chamber.running and tt.world.chamber.setpoint_c == 40.0


def test_espec_twin_reports_the_stuck_chamber_as_an_alarm() -> None:
    with TwinThread(EspecP300Twin) as tt, socket.create_connection(
        _host_port(tt.endpoint), timeout=5
    ) as sock:
        reader = sock.makefile("rb")
        tt.stick_chamber(report_fault=True)
        sock.sendall(b"MON?\r\nALARM?\r\n")
        assert reader.readline().split(b",")[3].strip() == b"1"
        assert reader.readline().strip() == f"1,{STUCK_ALARM_CODE}".encode()


def _f32_regs(value: float) -> list[int]:
    low, high = struct.unpack("<HH", struct.pack("<f", value))
    return [low, high]


def test_f4t_twin_takes_whole_float_pairs_and_refuses_the_rest() -> None:
    with TwinThread(WatlowF4TTwin) as tt:
        host, port = _host_port(tt.endpoint)
        client = ModbusTcpClient(host, port=port, timeout=2, retries=0)
        assert client.connect()
        try:
            ok = client.write_registers(2782, _f32_regs(42.5), device_id=1)
            assert not ok.isError() and tt.world.chamber.setpoint_c == 42.5
            torn = client.write_register(2782, 0, device_id=1)
            assert torn.isError() and torn.exception_code == 2
            beyond = client.write_registers(2782, _f32_regs(500.0), device_id=1)
            assert beyond.isError() and beyond.exception_code == 3
            read_only = client.write_registers(2820, _f32_regs(0.0), device_id=1)
            assert read_only.isError() and read_only.exception_code == 2
            manual = client.write_register(2730, 54, device_id=1)
            assert manual.isError() and manual.exception_code == 3
            auto = client.write_register(2730, 10, device_id=1)
            assert not auto.isError() and tt.world.chamber.running
            assert client.read_holding_registers(2814, count=1, device_id=1).registers == [10]
            tt.stick_chamber(report_fault=True)
            alarm = client.read_holding_registers(1356, count=1, device_id=1).registers[0]
            assert alarm == 53  # LOW: the air is below the 42.5 C setpoint
            assert tt.world.chamber.setpoint_c == 42.5
        finally:
            client.close()
