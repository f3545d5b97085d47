"""Conformance of `supply.keysight-e36300` to Keysight's E36300 Series Programming Guide: the
driver's exact bytes (a scripted instrument on a loopback socket) and the E36312A twin served
on its raw SCPI socket and over VXI-11, through pyvisa."""

from __future__ import annotations

import pytest

from drivers.errors import ScpiError
from drivers.keysight_e36300 import KeysightE36300Dialect
from drivers.supply import ScpiSupply
from tests.conformance._scpi_rig import (
    Served,
    check_error_queue,
    check_status_reporting,
    check_synchronisation,
    served,
)
from tests.conformance.table import Row, Table
from tests.drivers._scpi_fakes import NO_ERROR, ScriptedScpi
from tests.drivers.expected_protocol import Pair

GUIDE = "E36300 Series Programming Guide"
COMMON = f"{GUIDE}, IEEE-488.2 Common Commands"
TRANSPORTS = ["socket", "vxi11"]


def _row(item: str, meaning: str, section: str, driver: bool, test: str) -> Row:
    return Row(item, meaning, f"{GUIDE}, {section}" if section else COMMON, driver, True, test)


TABLE = Table(
    family="supply.keysight-e36300",
    instrument="Keysight E36311A, E36312A, E36313A triple-output supplies (the twin: E36312A)",
    sources=("Keysight E36300 Series Programming Guide", "Keysight E36300 Series data sheet",
             "IEEE Std 488.2-1992", "SCPI-1999"),
    rows=(
        _row("*IDN?", "Keysight Technologies,E36312A,serial,firmware", "", True,
             "test_identity_and_reset"),
        _row("*RST", "outputs off, 0 V, output 1 selected", "", True, "test_identity_and_reset"),
        _row("*CLS", "clear error queue and event registers", "", False,
             "test_status_reporting"),
        _row("*ESE / *ESE?", "standard event enable", "", False, "test_status_reporting"),
        _row("*ESR?", "standard event register (+NR1), cleared on reading", "", False,
             "test_status_reporting"),
        _row("*SRE / *SRE?", "service request enable", "", False, "test_status_reporting"),
        _row("*STB?", "status byte", "", False, "test_status_reporting"),
        _row("*OPC / *OPC?", "operation complete: 1 at once", "", False,
             "test_synchronisation_answers_at_once"),
        _row("*WAI", "wait for pending operations", "", False,
             "test_synchronisation_answers_at_once"),
        _row("*TST?", "self-test, +0 passed", "", False, "test_self_test"),
        _row("SYST:ERR?", "error queue, +0,\"No error\" when empty", "SYSTem Subsystem", True,
             "test_error_queue"),
        _row("SYST:VERS?", "SCPI version, 1999.0", "SYSTem Subsystem", False,
             "test_error_queue"),
        _row("INST:SEL CHn / INST?", "select the output bare commands act on", "INSTrument "
             "Subsystem", False, "test_selected_output"),
        _row("INST:NSEL n / INST:NSEL?", "select the output by number", "INSTrument Subsystem",
             False, "test_selected_output"),
        _row("VOLT <v>,(@n)", "an output's voltage; beyond its range -222", "SOURce Subsystem",
             True, "test_levels_and_ranges"),
        _row("VOLT? (@n)", "set voltage, NR3", "SOURce Subsystem", True,
             "test_levels_and_ranges"),
        _row("CURR <a>,(@n)", "an output's current limit; beyond its range -222",
             "SOURce Subsystem", True, "test_levels_and_ranges"),
        _row("CURR? (@n)", "set current limit, NR3", "SOURce Subsystem", True,
             "test_levels_and_ranges"),
        _row("VOLT? MAX,(@n) / CURR? MAX,(@n)", "the output's range (E36312A: 1: 6 V 5 A; "
             "2, 3: 25 V 1 A)", "Programming Ranges and Output Identifiers", False,
             "test_levels_and_ranges"),
        _row("APPL CHn,<v>,<a>", "an output's voltage and current at once", "APPLy Subsystem",
             False, "test_apply"),
        _row("APPL? CHn", "an output's voltage and current, NR3", "APPLy Subsystem", False,
             "test_apply"),
        _row("OUTP 1|0,(@list)", "outputs on or off", "OUTPut Subsystem", True,
             "test_outputs_and_measurements"),
        _row("OUTP? (@list)", "output states, 1/0 each", "OUTPut Subsystem", True,
             "test_outputs_and_measurements"),
        _row("MEAS:VOLT? (@n)", "measured voltage, NR3", "MEASure Subsystem", True,
             "test_outputs_and_measurements"),
        _row("MEAS:CURR? (@n)", "measured current, NR3", "MEASure Subsystem", True,
             "test_outputs_and_measurements"),
    ),
)


def nr1(value: int) -> str:
    return f"{value:+d}"


def _exchange(pairs: list[Pair], channel: int, act: object) -> None:
    fake = ScriptedScpi(pairs, "tcp")
    psu = ScpiSupply.open(fake.resource, timeout_s=0.5, dialect=KeysightE36300Dialect(channel))
    try:
        act(psu)  # type: ignore[operator]
    finally:
        psu.close()
        fake.close()
    fake.assert_done()


OK = Pair(b"SYST:ERR?\n", NO_ERROR)


@pytest.mark.parametrize("transport", TRANSPORTS)
def test_identity_and_reset(transport: str) -> None:
    _exchange([Pair(b"*IDN?\n", b"Keysight Technologies,E36312A,MY1,1.0\n"), Pair(b"*RST\n"),
               OK], 1, lambda psu: (psu.identify(), psu.reset()))
    with served("keysight-e36300", transport) as rig:
        assert rig.ask("*IDN?").startswith("Keysight Technologies,E36312A,")
        rig.send("INST:NSEL 3;:VOLT 5;:OUTP ON")
        rig.send("*RST")
        assert (rig.ask("INST:NSEL?"), rig.ask("OUTP? (@1:3)")) == ("+1", "0,0,0")


@pytest.mark.parametrize("transport", TRANSPORTS)
def test_status_reporting(transport: str) -> None:
    with served("keysight-e36300", transport) as rig:
        check_status_reporting(rig, nr1, "FROB 1")


@pytest.mark.parametrize("transport", TRANSPORTS)
def test_synchronisation_answers_at_once(transport: str) -> None:
    with served("keysight-e36300", transport) as rig:
        check_synchronisation(rig, nr1)


def test_self_test() -> None:
    with served("keysight-e36300", "socket") as rig:
        assert rig.ask("*TST?") == "+0"


def test_error_queue() -> None:
    with pytest.raises(ScpiError, match="-222"):
        _exchange([Pair(b"VOLT 5.250,(@2)\n"),
                   Pair(b"SYST:ERR?\n", b'-222,"Data out of range"\n'), OK], 2,
                  lambda psu: psu.set_voltage(5.25))
    with served("keysight-e36300", "socket") as rig:
        check_error_queue(rig, "SYST:ERR?", "FROB 1", '+0,"No error"')
        assert rig.ask("SYST:VERS?") == "1999.0"


@pytest.mark.parametrize("transport", TRANSPORTS)
def test_selected_output(transport: str) -> None:
    """After INST:SEL CH2 a bare VOLT lands on output 2 (issue 41: it landed on output 1)."""
    with served("keysight-e36300", transport, channel=2) as rig:
        rig.send("INST:SEL CH2")
        rig.send("VOLT 3.3")
        assert rig.ask("INST?") == "CH2" and rig.ask("INST:NSEL?") == "+2"
        assert rig.ask("VOLT? (@1:3)") == "+0.00000000E+00,+3.30000000E+00,+0.00000000E+00"
        assert rig.world.supply.voltage_set_v == pytest.approx(3.3)  # the parts' output
        rig.send("INST:NSEL 3;:CURR 0.5")
        assert rig.ask("CURR?") == "+5.00000000E-01"
        rig.send("INST:NSEL 4")
        assert rig.errors() == ['-222,"Data out of range"']


def _ranges(rig: Served) -> dict[int, tuple[float, float]]:
    return {n: (float(rig.ask(f"VOLT? MAX,(@{n})")), float(rig.ask(f"CURR? MAX,(@{n})")))
            for n in (1, 2, 3)}


@pytest.mark.parametrize("transport", TRANSPORTS)
def test_levels_and_ranges(transport: str) -> None:
    _exchange([Pair(b"VOLT 5.250,(@1)\n"), OK, Pair(b"CURR 0.1000,(@1)\n"), OK,
               Pair(b"*IDN?\n", b"Keysight Technologies,E36312A,MY1,1.0\n")], 1,
              lambda psu: (psu.set_voltage(5.25), psu.set_current_limit(0.1),
                           _range_is(psu, 6.0, 5.0)))
    with served("keysight-e36300", transport) as rig:
        assert _ranges(rig) == {1: (6.0, 5.0), 2: (25.0, 1.0), 3: (25.0, 1.0)}
        rig.send("VOLT 10,(@1)")  # accepted before issue 41
        rig.send("CURR 1.5,(@2)")
        rig.send("VOLT 6,(@1)")
        rig.send("CURR 0.9,(@2)")
        assert rig.errors() == ['-222,"Data out of range"'] * 2
        assert (rig.ask("VOLT? (@1)"), rig.ask("CURR? (@2)")) == (
            "+6.00000000E+00", "+9.00000000E-01")


def _range_is(psu: ScpiSupply, volts: float, amps: float) -> None:
    found = psu.output_range()
    assert found is not None and (found.high_v, found.max_a) == (volts, amps)
    assert found.output == "output 1 of the Keysight E36312A"


@pytest.mark.parametrize("transport", TRANSPORTS)
def test_apply(transport: str) -> None:
    with served("keysight-e36300", transport) as rig:
        rig.send("APPL CH2,12.5,0.25")
        assert rig.ask("APPL? CH2") == "+1.25000000E+01,+2.50000000E-01"
        rig.send("APPL CH1,7,0.1")  # beyond output 1's 6 V: nothing changes
        assert rig.errors() == ['-222,"Data out of range"']
        assert rig.ask("APPL? CH1") == "+0.00000000E+00,+1.00000000E-01"


@pytest.mark.parametrize("transport", TRANSPORTS)
def test_outputs_and_measurements(transport: str) -> None:
    _exchange([Pair(b"OUTP 1,(@3)\n"), OK, Pair(b"OUTP? (@3)\n", b"1\n"),
               Pair(b"MEAS:VOLT? (@3)\n", b"+5.00010000E+00\n"),
               Pair(b"MEAS:CURR? (@3)\n", b"+2.50000000E-02\n")], 3,
              lambda psu: (psu.output(True), psu.output_is_on(), psu.measure_voltage(),
                           psu.measure_current()))
    with served("keysight-e36300", transport) as rig:
        rig.send("VOLT 5,(@1);:OUTP 1,(@1,2)")
        assert rig.ask("OUTP? (@1:3)") == "1,1,0"
        assert float(rig.ask("MEAS:VOLT? (@1)")) == pytest.approx(5.0, abs=2e-3)
        assert float(rig.ask("MEAS:CURR? (@1)")) > 0.005  # the part draws from output 1
        assert float(rig.ask("MEAS:CURR? (@2)")) == pytest.approx(0.0, abs=1e-4)
