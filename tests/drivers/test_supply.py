"""SCPI supply: exact bytes on the wire, error queue after every setting, constant-current
detection, partial lines, a real pty, and property-based tests of the SCPI line reader."""

from __future__ import annotations

import os
import threading
import time
import tty

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.errors import (
    InstrumentTimeout,
    ProtocolError,
    ScpiError,
    SupplyCurrentLimit,
)
from drivers.scpi import MAX_LINE_BYTES, LineReader, ScpiPort, parse_error_reply
from drivers.supply import ScpiSupply
from tests.drivers._fakes import ExpectedSerial

NO_ERR = (b"SYST:ERR?\n", b'+0,"No error"\n')


def make(script, timeout_s=0.3):
    port = ExpectedSerial(script, timeout=0.01)
    return port, ScpiSupply(port, timeout_s=timeout_s)


def finish(port):
    assert port.errors == []
    assert port.done, f"unused script: {port.script}"


def test_identify():
    port, supply = make([(b"*IDN?\n", b"Keysight Technologies,E36102B,MY5900123,1.0.4\r\n")])
    ident = supply.identify()
    assert ident.manufacturer == "Keysight Technologies"
    assert (ident.model, ident.serial, ident.firmware) == ("E36102B", "MY5900123", "1.0.4")
    finish(port)


def test_identify_rejects_a_reply_that_is_not_an_idn():
    port, supply = make([(b"*IDN?\n", b"hello\n")])
    with pytest.raises(ProtocolError, match="really the supply"):
        supply.identify()
    finish(port)


def test_each_setting_is_followed_by_the_error_queue():
    port, supply = make([
        (b"VOLT 4.750\n", b""), NO_ERR,
        (b"CURR 0.1000\n", b""), NO_ERR,
        (b"OUTP ON\n", b""), NO_ERR,
        (b"OUTP OFF\n", b""), NO_ERR,
        (b"*RST\n", b""), NO_ERR,
    ])
    supply.set_voltage(4.75)
    supply.set_current_limit(0.1)
    supply.output(True)
    supply.output(False)
    supply.reset()
    finish(port)


def test_refused_setting_raises_scpi_error_with_code_and_drains_the_queue():
    port, supply = make([
        (b"VOLT 30.000\n", b""),
        (b"SYST:ERR?\n", b'-222,"Data out of range"\n'),
        (b"SYST:ERR?\n", b'-113,"Undefined header"\n'),
        NO_ERR,
    ])
    with pytest.raises(ScpiError, match=r"'VOLT 30.000'.*-222 Data out of range.*1 more") as info:
        supply.set_voltage(30.0)
    assert info.value.code == -222
    finish(port)


def test_queries_parse_numbers_and_output_state():
    port, supply = make([
        (b"MEAS:VOLT?\n", b"4.7496\n"),
        (b"MEAS:CURR?\n", b"0.021300\n"),
        (b"OUTP?\n", b"1\n"),
        (b"OUTP?\n", b"0\n"),
        (b"MEAS:VOLT?\n", b"4.7x\n"),
    ])
    assert supply.measure_voltage() == 4.7496
    assert supply.measure_current() == 0.0213
    assert supply.output_is_on() is True
    assert supply.output_is_on() is False
    with pytest.raises(ProtocolError, match="not a number"):
        supply.measure_voltage()
    finish(port)


def test_partial_line_is_never_taken_as_a_value():
    port, supply = make([(b"MEAS:VOLT?\n", b"4.74")], timeout_s=0.15)
    t0 = time.monotonic()
    with pytest.raises(InstrumentTimeout, match="unfinished line"):
        supply.measure_voltage()
    assert 0.15 <= time.monotonic() - t0 < 0.6
    finish(port)


def test_shorted_part_raises_current_limit():
    port, supply = make([
        (b"VOLT 5.000\n", b""), NO_ERR,
        (b"CURR 0.1000\n", b""), NO_ERR,
        (b"MEAS:VOLT?\n", b"0.3100\n"),
        (b"MEAS:CURR?\n", b"0.099990\n"),
    ])
    supply.set_voltage(5.0)
    supply.set_current_limit(0.1)
    with pytest.raises(SupplyCurrentLimit, match="shorted"):
        supply.check_current_limit()
    finish(port)


def test_healthy_part_passes_the_current_check_reading_setpoints_when_unknown():
    port, supply = make([
        (b"VOLT?\n", b"5.2500\n"),
        (b"CURR?\n", b"0.1000\n"),
        (b"MEAS:VOLT?\n", b"5.2498\n"),
        (b"MEAS:CURR?\n", b"0.024000\n"),
    ])
    assert supply.check_current_limit() == (5.2498, 0.024)
    finish(port)


def test_late_reply_to_a_timed_out_query_does_not_answer_the_next():
    class LatePort(ExpectedSerial):
        def write(self, data):
            n = super().write(data)
            if data == b"MEAS:VOLT?\n":
                late = bytes(self._rx)
                self._rx.clear()
                threading.Timer(0.2, lambda: self._rx.extend(late)).start()
            return n

    port = LatePort([(b"MEAS:VOLT?\n", b"4.0000\n"), (b"MEAS:CURR?\n", b"0.020000\n")], 0.01)
    supply = ScpiSupply(port, timeout_s=0.1)
    with pytest.raises(InstrumentTimeout):
        supply.measure_voltage()
    time.sleep(0.25)  # the stale "4.0000" is now waiting in the input
    assert supply.measure_current() == 0.02
    finish(port)


def test_against_a_real_pty_with_pyserial():
    master, slave = os.openpty()
    tty.setraw(slave)
    seen: list[bytes] = []
    stop = threading.Event()

    def instrument():
        buf = b""
        while not stop.is_set():
            try:
                buf += os.read(master, 256)
            except OSError:
                return
            while b"\n" in buf:
                line, buf = buf.split(b"\n", 1)
                seen.append(line)
                if line == b"*IDN?":
                    os.write(master, b"SIM,PSU-1,0001,1.0\n")
                elif line == b"SYST:ERR?":
                    os.write(master, b'+0,"No error"\n')

    worker = threading.Thread(target=instrument, daemon=True)
    worker.start()
    supply = ScpiSupply.open(os.ttyname(slave), timeout_s=1.0)
    try:
        assert supply.identify().model == "PSU-1"
        supply.set_voltage(5.25)
        assert seen == [b"*IDN?", b"VOLT 5.250", b"SYST:ERR?"]
    finally:
        supply.close()
        stop.set()
        os.close(master)
        worker.join(1)
        os.close(slave)


# ---------------------------------------------------------------- property-based


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=2000), st.integers(1, 300))
def test_line_reader_on_arbitrary_bytes(data, chunk):
    reader = LineReader(max_line_bytes=64)
    lines = []
    for i in range(0, len(data), chunk):
        lines += reader.feed(data[i : i + chunk])
    assert all("\n" not in line and len(line) <= 64 for line in lines)
    assert reader.pending <= 64
    # every complete line that fits is delivered, exactly and in order
    expected = [
        p.decode("ascii", "replace").rstrip("\r") for p in data.split(b"\n")[:-1] if len(p) <= 64
    ]
    assert lines == expected


@settings(max_examples=200, deadline=None)
@given(st.text(max_size=80))
def test_error_reply_parser_either_parses_or_says_protocol_error(text):
    try:
        code, message = parse_error_reply(text)
    except ProtocolError:
        return
    assert isinstance(code, int) and isinstance(message, str)
    assert str(code) in text.replace("+", "")


class _NoisePort:
    def __init__(self, noise: bytes) -> None:
        self._rx = bytearray(noise)
        self.in_waiting = 0

    def write(self, data):
        self.in_waiting = len(self._rx)
        return len(data)

    def read(self, size=1):
        out = bytes(self._rx[:size])
        del self._rx[:size]
        self.in_waiting = len(self._rx)
        if not out:
            time.sleep(0.002)
        return out

    def reset_input_buffer(self):
        pass

    def close(self):
        pass


@settings(max_examples=60, deadline=None)
@given(st.binary(max_size=3 * MAX_LINE_BYTES))
def test_scpi_query_on_noise_returns_a_line_or_a_typed_error_in_time(noise):
    scpi = ScpiPort(_NoisePort(noise), timeout_s=0.02)
    t0 = time.monotonic()
    try:
        line = scpi.query("MEAS:VOLT?")
    except InstrumentTimeout:
        assert b"\n" not in noise or all(
            len(p) > MAX_LINE_BYTES for p in noise.split(b"\n")[:-1]
        )
    else:
        assert "\n" not in line and len(line) <= MAX_LINE_BYTES
        first = next(p for p in noise.split(b"\n")[:-1] if len(p) <= MAX_LINE_BYTES)
        assert line == first.decode("ascii", "replace").rstrip("\r")
    assert time.monotonic() - t0 < 0.5


def test_supply_driver_satisfies_the_supply_protocol():
    from drivers.protocols import Supply

    assert isinstance(ScpiSupply(ExpectedSerial([])), Supply)
