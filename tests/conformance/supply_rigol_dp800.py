"""Conformance of `supply.rigol-dp800` to Rigol's DP800 Series Programming Guide: the driver's
exact bytes (a scripted instrument on a loopback socket) and the DP832 twin served on its raw
SCPI socket and over VXI-11, through pyvisa."""

from __future__ import annotations

import pytest

from drivers.errors import ScpiError
from drivers.rigol_dp800 import RigolDp800Dialect
from drivers.supply import ScpiSupply
from tests.conformance._scpi_rig import (
    check_error_queue,
    check_status_reporting,
    check_synchronisation,
    served,
)
from tests.conformance.table import Row, Table
from tests.drivers._scpi_fakes import ScriptedScpi
from tests.drivers.expected_protocol import Pair

GUIDE = "DP800 Series Programming Guide"
TRANSPORTS = ["socket", "vxi11"]


def _row(item: str, meaning: str, section: str, driver: bool, test: str) -> Row:
    return Row(item, meaning, f"{GUIDE}, {section}", driver, True, test)


COMMON = "IEEE488.2 Common Commands"
TABLE = Table(
    family="supply.rigol-dp800",
    instrument="Rigol DP832/DP832A, DP831, DP821 supplies (the twin: DP832)",
    sources=("Rigol DP800 Series Programming Guide", "Rigol DP800 Series data sheet",
             "IEEE Std 488.2-1992", "SCPI-1999"),
    rows=(
        _row("*IDN?", "RIGOL TECHNOLOGIES,DP832,serial,firmware", COMMON, True,
             "test_identity_and_reset"),
        _row("*RST", "channels off, CH1 selected, protection off", COMMON, False,
             "test_identity_and_reset"),
        _row("*CLS", "clear error queue and event registers", COMMON, False,
             "test_status_reporting"),
        _row("*ESE / *ESE?", "standard event enable", COMMON, False, "test_status_reporting"),
        _row("*ESR?", "standard event register (NR1), cleared on reading", COMMON, False,
             "test_status_reporting"),
        _row("*SRE / *SRE?", "service request enable", COMMON, False, "test_status_reporting"),
        _row("*STB?", "status byte", COMMON, False, "test_status_reporting"),
        _row("*OPC / *OPC?", "operation complete: 1 at once", COMMON, False,
             "test_synchronisation_answers_at_once"),
        _row("*WAI", "wait for pending operations", COMMON, False,
             "test_synchronisation_answers_at_once"),
        _row("*TST?", "TopBoard:PASS,BottomBoard:PASS,Fan:PASS", COMMON, False,
             "test_self_test"),
        _row(":SYST:ERR?", "error queue, 0,\"No error\" when empty", ":SYSTem Commands", True,
             "test_error_queue"),
        _row(":SYST:VERS?", "SCPI version, 1999.0", ":SYSTem Commands", False,
             "test_error_queue"),
        _row(":INST CHn / :INST?", "select the channel bare commands act on",
             ":INSTrument Commands", False, "test_selected_channel"),
        _row(":INST:NSEL n / :INST:NSEL?", "select by number", ":INSTrument Commands", True,
             "test_selected_channel"),
        _row(":VOLT <v> / :SOURn:VOLT?", "a channel's voltage; beyond its programming range "
             "(CH1, CH2 32 V; CH3 5.3 V) -222", ":SOURce Commands", True,
             "test_levels_and_ranges"),
        _row(":CURR <a> / :SOURn:CURR?", "a channel's current limit; beyond 3.2 A -222",
             ":SOURce Commands", True, "test_levels_and_ranges"),
        _row(":APPL CHn,<v>,<a>", "a channel's voltage and current at once", ":APPLy", False,
             "test_apply"),
        _row(":APPL? CHn", "CH1:30V/3A,5.000,0.100 (rating, voltage, current)", ":APPLy", False,
             "test_apply"),
        _row(":APPL? CHn,VOLT|CURR", "the set voltage or current", ":APPLy", True, "test_apply"),
        _row(":OUTP CHn,ON|OFF", "a channel on or off", ":OUTPut Commands", True,
             "test_outputs_and_measurements"),
        _row(":OUTP? CHn", "ON/OFF", ":OUTPut Commands", True, "test_outputs_and_measurements"),
        _row(":OUTP:MODE? CHn", "CV/CC", ":OUTPut Commands", False,
             "test_outputs_and_measurements"),
        _row(":MEAS:VOLT? CHn", "measured voltage", ":MEASure Commands", True,
             "test_outputs_and_measurements"),
        _row(":MEAS:CURR? CHn", "measured current", ":MEASure Commands", True,
             "test_outputs_and_measurements"),
        _row(":MEAS:POWE? CHn", "measured power", ":MEASure Commands", False,
             "test_outputs_and_measurements"),
        _row(":MEAS:ALL? CHn", "voltage,current,power", ":MEASure Commands", False,
             "test_outputs_and_measurements"),
        _row(":OUTP:OVP CHn,ON|OFF / :OUTP:OVP? CHn", "over-voltage protection on/off",
             ":OUTPut Commands", False, "test_protection"),
        _row(":OUTP:OVP:VAL CHn,<v> / :OUTP:OVP:VAL? CHn", "OVP level (0.01 to 33 V)",
             ":OUTPut Commands", False, "test_protection"),
        _row(":OUTP:OVP:ALAR? CHn / :OUTP:OVP:CLEAR CHn", "tripped (YES/NO), and its clearing",
             ":OUTPut Commands", False, "test_protection"),
        _row(":OUTP:OCP... (as OVP)", "over-current protection (0.001 to 3.3 A)",
             ":OUTPut Commands", False, "test_protection"),
    ),
)

ERR = b":SYST:ERR?\n"
OK = Pair(ERR, b'0,"No error"\n')


def _exchange(pairs: list[Pair], channel: int, act: object) -> None:
    fake = ScriptedScpi(pairs, "tcp")
    psu = ScpiSupply.open(fake.resource, timeout_s=0.5, dialect=RigolDp800Dialect(channel))
    try:
        act(psu)  # type: ignore[operator]
    finally:
        psu.close()
        fake.close()
    fake.assert_done()


def nr1(value: int) -> str:
    return str(value)


@pytest.mark.parametrize("transport", TRANSPORTS)
def test_identity_and_reset(transport: str) -> None:
    _exchange([Pair(b"*IDN?\n", b"RIGOL TECHNOLOGIES,DP832A,DP8A1,00.01.14\n")], 1,
              lambda psu: _rating_is(psu, 30.0, 3.0))
    with served("rigol-dp800", transport) as rig:
        assert rig.ask("*IDN?").startswith("RIGOL TECHNOLOGIES,DP832,")
        rig.send(":INST CH3;:OUTP CH3,ON;:OUTP:OVP CH3,ON")
        rig.send("*RST")
        assert (rig.ask(":INST?"), rig.ask(":OUTP? CH3"), rig.ask(":OUTP:OVP? CH3")) == (
            "CH1", "OFF", "OFF")


def _rating_is(psu: ScpiSupply, volts: float, amps: float) -> None:
    """The DP832A is a DP832: CH1 rated 30 V / 3 A (the pre-flight's range)."""
    found = psu.output_range()
    assert found is not None and (found.high_v, found.max_a) == (volts, amps)
    assert found.output == "CH1 of the Rigol DP832A"


@pytest.mark.parametrize("transport", TRANSPORTS)
def test_status_reporting(transport: str) -> None:
    with served("rigol-dp800", transport) as rig:
        check_status_reporting(rig, nr1, ":FROB 1")


@pytest.mark.parametrize("transport", TRANSPORTS)
def test_synchronisation_answers_at_once(transport: str) -> None:
    with served("rigol-dp800", transport) as rig:
        check_synchronisation(rig, nr1)


def test_self_test() -> None:
    with served("rigol-dp800", "socket") as rig:
        assert rig.ask("*TST?") == "TopBoard:PASS,BottomBoard:PASS,Fan:PASS"


def test_error_queue() -> None:
    with pytest.raises(ScpiError, match="-222"):
        _exchange([Pair(b":INST:NSEL 3;:VOLT 6.000\n"),
                   Pair(ERR, b'-222,"Data out of range"\n'), OK], 3,
                  lambda psu: psu.set_voltage(6.0))
    with served("rigol-dp800", "socket") as rig:
        check_error_queue(rig, ":SYST:ERR?", ":FROB 1", '0,"No error"')
        assert rig.ask(":SYST:VERS?") == "1999.0"


@pytest.mark.parametrize("transport", TRANSPORTS)
def test_selected_channel(transport: str) -> None:
    _exchange([Pair(b":INST:NSEL 2;:VOLT 5.000\n"), OK], 2, lambda psu: psu.set_voltage(5.0))
    with served("rigol-dp800", transport, channel=2) as rig:
        rig.send(":INST CH2")
        rig.send(":VOLT 3.3")
        assert (rig.ask(":INST?"), rig.ask(":INST:NSEL?")) == ("CH2", "2")
        assert rig.world.supply.voltage_set_v == pytest.approx(3.3)
        assert rig.ask(":SOUR1:VOLT?") == "0.000"


@pytest.mark.parametrize("transport", TRANSPORTS)
def test_levels_and_ranges(transport: str) -> None:
    _exchange([Pair(b":INST:NSEL 1;:CURR 0.1000\n"), OK], 1,
              lambda psu: psu.set_current_limit(0.1))
    with served("rigol-dp800", transport) as rig:
        assert [rig.ask(f":SOUR{n}:VOLT? MAX") for n in (1, 2, 3)] == ["32.000", "32.000",
                                                                      "5.300"]
        assert rig.ask(":SOUR3:CURR? MAX") == "3.200"
        rig.send(":SOUR3:VOLT 5.2;:SOUR3:VOLT 5.4")
        rig.send(":SOUR1:CURR 3.3")
        assert rig.errors(":SYST:ERR?") == ['-222,"Data out of range"'] * 2
        assert (rig.ask(":SOUR3:VOLT?"), rig.ask(":SOUR1:CURR?")) == ("5.200", "0.100")


@pytest.mark.parametrize("transport", TRANSPORTS)
def test_apply(transport: str) -> None:
    _exchange([Pair(b":APPL? CH1,VOLT\n", b"5.000\n"), Pair(b":APPL? CH1,CURR\n", b"0.100\n"),
               Pair(b":MEAS:VOLT? CH1\n", b"5.0001\n"), Pair(b":MEAS:CURR? CH1\n", b"0.0100\n")],
              1, lambda psu: psu.check_current_limit())
    with served("rigol-dp800", transport) as rig:
        rig.send(":APPL CH2,12.5,0.25")
        assert rig.ask(":APPL? CH2") == "CH2:30V/3A,12.500,0.250"
        assert (rig.ask(":APPL? CH2,VOLT"), rig.ask(":APPL? CH2,CURR")) == ("12.500", "0.250")
        assert rig.ask(":APPL? CH3") == "CH3:5V/3A,0.000,0.100"


@pytest.mark.parametrize("transport", TRANSPORTS)
def test_outputs_and_measurements(transport: str) -> None:
    _exchange([Pair(b":OUTP CH1,ON\n"), OK, Pair(b":OUTP? CH1\n", b"ON\n"),
               Pair(b":MEAS:VOLT? CH1\n", b"5.0001\n"), Pair(b":MEAS:CURR? CH1\n", b"0.0250\n")],
              1, lambda psu: (psu.output(True), psu.output_is_on(), psu.measure_voltage(),
                              psu.measure_current()))
    with served("rigol-dp800", transport) as rig:
        rig.send(":APPL CH1,5,0.1;:OUTP CH1,ON")
        assert (rig.ask(":OUTP? CH1"), rig.ask(":OUTP? CH2")) == ("ON", "OFF")
        assert rig.ask(":OUTP:MODE? CH1") == "CV"
        volts, amps, watts = (float(v) for v in rig.ask(":MEAS:ALL? CH1").split(","))
        assert volts == pytest.approx(5.0, abs=2e-3) and amps > 0.005
        assert watts == pytest.approx(volts * amps, abs=2e-3)
        assert float(rig.ask(":MEAS:POWE? CH1")) == pytest.approx(watts, abs=2e-3)
        assert float(rig.ask(":MEAS:VOLT? CH1")) == pytest.approx(5.0, abs=2e-3)
        assert float(rig.ask(":MEAS:CURR? CH2")) == 0.0


@pytest.mark.parametrize("transport", TRANSPORTS)
def test_protection(transport: str) -> None:
    with served("rigol-dp800", transport) as rig:
        assert (rig.ask(":OUTP:OVP? CH1"), rig.ask(":OUTP:OVP:VAL? CH1")) == ("OFF", "33.000")
        rig.send(":APPL CH1,5,0.1;:OUTP:OVP:VAL CH1,4;:OUTP:OVP CH1,ON;:OUTP CH1,ON")
        assert (rig.ask(":OUTP:OVP:ALAR? CH1"), rig.ask(":OUTP? CH1")) == ("YES", "OFF")
        rig.send(":OUTP CH1,ON")  # stays off while tripped
        assert rig.ask(":OUTP? CH1") == "OFF"
        rig.send(":OUTP:OVP:CLEAR CH1;:OUTP:OVP CH1,OFF;:OUTP CH1,ON")
        assert (rig.ask(":OUTP:OVP:ALAR? CH1"), rig.ask(":OUTP? CH1")) == ("NO", "ON")
        rig.send(":OUTP:OCP:VAL CH1,0.001;:OUTP:OCP CH1,ON")  # the part draws more than 1 mA
        assert (rig.ask(":OUTP:OCP:ALAR? CH1"), rig.ask(":OUTP? CH1")) == ("YES", "OFF")
        assert rig.ask(":OUTP:OCP:VAL? CH1") == "0.001"
        rig.send(":OUTP:OVP:VAL CH3,6")  # CH3's OVP goes to 5.5 V
        assert rig.errors(":SYST:ERR?") == ['-222,"Data out of range"']
