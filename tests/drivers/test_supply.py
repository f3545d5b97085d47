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
from drivers.scpi import parse_error_reply
from drivers.supply import ScpiSupply
from tests.drivers._scpi_fakes import ScriptedScpi
from tests.drivers.expected_protocol import Pair, finish

NO_ERR = (b"SYST:ERR?\n", b'+0,"No error"\n')


class _Rig:
    """A scripted instrument on a pty and the driver on it through pyvisa's ASRL resource."""

    def __init__(self, script, timeout_s):
        self.fake = ScriptedScpi([Pair(*step) for step in script], "pty")
        self.supply = ScpiSupply.open(self.fake.path, timeout_s=timeout_s)


_rigs: list[_Rig] = []


@pytest.fixture(autouse=True)
def _close_rigs():
    yield
    while _rigs:
        rig = _rigs.pop()
        rig.supply.close()
        rig.fake.close()


def make(script, timeout_s=0.3):
    rig = _Rig(script, timeout_s)
    _rigs.append(rig)
    return rig.fake, rig.supply


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
    with pytest.raises(InstrumentTimeout, match="did not answer 'MEAS:VOLT\\?' within 0.15 s"):
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
    port, supply = make(
        [(b"MEAS:VOLT?\n", b"4.0000\n", 0.2), (b"MEAS:CURR?\n", b"0.020000\n")], timeout_s=0.1
    )
    with pytest.raises(InstrumentTimeout):
        supply.measure_voltage()
    time.sleep(0.25)  # the stale "4.0000" is now waiting in the input
    assert supply.measure_current() == 0.02
    finish(port)


def test_against_a_real_pty_given_as_a_plain_device_path():
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


@settings(max_examples=200, deadline=None)
@given(st.text(max_size=80))
def test_error_reply_parser_either_parses_or_says_protocol_error(text):
    try:
        code, message = parse_error_reply(text)
    except ProtocolError:
        return
    assert isinstance(code, int) and isinstance(message, str)
    assert str(code) in text.replace("+", "")


@settings(max_examples=25, deadline=None)
@given(st.binary(max_size=600))
def test_query_on_noise_returns_the_first_line_or_a_typed_error_in_time(noise):
    fake = ScriptedScpi([Pair(b"MEAS:VOLT?\n", noise)], "pty")
    supply = ScpiSupply.open(fake.path, timeout_s=0.05)
    t0 = time.monotonic()
    try:
        value = supply.measure_voltage()
    except InstrumentTimeout:
        assert b"\n" not in noise
    except ProtocolError:
        assert b"\n" in noise
    else:
        first = noise.split(b"\n")[0].decode("latin-1").rstrip("\r")
        assert value == float(first)
    finally:
        supply.close()
        fake.close()
    assert time.monotonic() - t0 < 1.0


def test_supply_driver_satisfies_the_supply_protocol():
    from drivers.protocols import Supply

    port, supply = make([])
    assert isinstance(supply, Supply)
