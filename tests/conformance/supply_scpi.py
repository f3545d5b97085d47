"""Conformance of `supply.scpi` (a generic single-output SCPI supply) to SCPI-1999 and IEEE
488.2: the driver's exact bytes (a scripted instrument on a real pseudo-terminal) and the
bench's pty twin through pyvisa's ASRL resource, as the station reaches it."""

from __future__ import annotations

import pytest

from drivers.errors import ScpiError
from drivers.supply import ScpiDialect, ScpiSupply
from tests.conformance._scpi_rig import (
    check_error_queue,
    check_status_reporting,
    check_synchronisation,
    served,
)
from tests.conformance.table import Row, Table
from tests.drivers._scpi_fakes import NO_ERROR, ScriptedScpi
from tests.drivers.expected_protocol import Pair

IEEE = "IEEE 488.2-1992, 10 (common commands)"
SCPI = "SCPI-1999 vol. 1, 4.2.1 (required commands)"
SOURCE = "SCPI-1999 vol. 2, SOURce / OUTPut / MEASure"


def _row(item: str, meaning: str, section: str, driver: bool, test: str) -> Row:
    return Row(item, meaning, section, driver, True, test)


TABLE = Table(
    family="supply.scpi",
    instrument="a generic single-output SCPI-1999 DC supply (no maker's product; the twin's "
               "*IDN? names the simulated bench)",
    sources=("IEEE Std 488.2-1992", "SCPI-1999 vols. 1-2"),
    rows=(
        _row("*IDN?", "maker, model, serial, firmware", IEEE, True, "test_identity_and_reset"),
        _row("*RST", "settings to reset values (status kept)", IEEE, True,
             "test_identity_and_reset"),
        _row("*CLS", "clear error queue and event registers", IEEE, False,
             "test_status_reporting"),
        _row("*ESE", "standard event enable", IEEE, False, "test_status_reporting"),
        _row("*ESE?", "standard event enable", IEEE, False, "test_status_reporting"),
        _row("*ESR?", "standard event register, cleared on reading", IEEE, False,
             "test_status_reporting"),
        _row("*SRE", "service request enable", IEEE, False, "test_status_reporting"),
        _row("*SRE?", "service request enable", IEEE, False, "test_status_reporting"),
        _row("*STB?", "status byte (queue, QUES, MAV, ESB, MSS, OPER)", IEEE, False,
             "test_status_reporting"),
        _row("*OPC", "operation complete bit set when done", IEEE, False,
             "test_synchronisation_answers_at_once"),
        _row("*OPC?", "1 when every operation is done", IEEE, False,
             "test_synchronisation_answers_at_once"),
        _row("*WAI", "wait for pending operations", IEEE, False,
             "test_synchronisation_answers_at_once"),
        _row("*TST?", "self-test, +0 passed", IEEE, False, "test_self_test"),
        _row("SYST:ERR?", "error queue, first in first out, -350 on overflow", SCPI, True,
             "test_error_queue"),
        _row("SYST:VERS?", "SCPI version, 1999.0", SCPI, False, "test_scpi_version"),
        _row("STAT:QUES?", "questionable event (bit 0: voltage not held, CC)", SCPI, False,
             "test_status_registers"),
        _row("STAT:QUES:COND?", "questionable condition", SCPI, False, "test_status_registers"),
        _row("STAT:QUES:ENAB", "questionable enable, summarised in *STB? bit 3", SCPI, False,
             "test_status_registers"),
        _row("STAT:OPER?", "operation event", SCPI, False, "test_status_registers"),
        _row("STAT:OPER:COND?", "operation condition", SCPI, False, "test_status_registers"),
        _row("STAT:OPER:ENAB", "operation enable", SCPI, False, "test_status_registers"),
        _row("STAT:PRES", "QUES and OPER enables to 0", SCPI, False, "test_status_registers"),
        _row("VOLT <v>", "output voltage; beyond the range -222, nothing changed", SOURCE, True,
             "test_levels"),
        _row("VOLT?", "set voltage", SOURCE, True, "test_levels"),
        _row("CURR <a>", "current limit; beyond the range -222", SOURCE, True, "test_levels"),
        _row("CURR?", "set current limit", SOURCE, True, "test_levels"),
        _row("VOLT? MAX", "the output's highest voltage (the pre-flight's range)",
             "SCPI-1999 vol. 1, 7.2.1.2 (MINimum|MAXimum)", True, "test_range_queries"),
        _row("CURR? MAX", "the output's highest current limit",
             "SCPI-1999 vol. 1, 7.2.1.2 (MINimum|MAXimum)", True, "test_range_queries"),
        _row("OUTP ON|OFF", "output on or off", SOURCE, True, "test_output_and_measure"),
        _row("OUTP?", "output state, 1/0", SOURCE, True, "test_output_and_measure"),
        _row("MEAS:VOLT?", "measured output voltage", SOURCE, True, "test_output_and_measure"),
        _row("MEAS:CURR?", "measured output current", SOURCE, True, "test_output_and_measure"),
    ),
)

ERR = b"SYST:ERR?\n"
OK = Pair(ERR, NO_ERROR)


def _driver(fake: ScriptedScpi) -> ScpiSupply:
    return ScpiSupply.open(fake.resource, timeout_s=0.5, dialect=ScpiDialect())


def _exchange(pairs: list[Pair], act: object) -> None:
    fake = ScriptedScpi(pairs, "pty")
    psu = _driver(fake)
    try:
        act(psu)  # type: ignore[operator]
    finally:
        psu.close()
        fake.close()
    fake.assert_done()


def nr1(value: int) -> str:
    return f"{value:+d}"


def test_identity_and_reset() -> None:
    _exchange([Pair(b"*IDN?\n", b"Maker,Model-1,SN1,1.0\n"), Pair(b"*RST\n"), OK],
              lambda psu: (psu.identify(), psu.reset()))
    with served("scpi", "pty") as rig:
        maker, model, serial, firmware = rig.ask("*IDN?").split(",")
        assert (maker, model) == ("GYROCAL SIMULATED BENCH", "SCPI SUPPLY TWIN")
        rig.send("VOLT 5;OUTP ON;*ESE 4")
        rig.send("*RST")
        assert (rig.ask("VOLT?"), rig.ask("OUTP?")) == ("0.0000", "0")
        assert rig.ask("*ESE?") == "+4"  # *RST leaves the status reporting alone


def test_status_reporting() -> None:
    with served("scpi", "pty") as rig:
        check_status_reporting(rig, nr1, "FROB 1")


def test_synchronisation_answers_at_once() -> None:
    with served("scpi", "pty") as rig:
        check_synchronisation(rig, nr1)


def test_self_test() -> None:
    with served("scpi", "pty") as rig:
        assert rig.ask("*TST?") == "+0"


def test_error_queue() -> None:
    pairs = [Pair(b"VOLT 45.000\n"), Pair(ERR, b'-222,"Data out of range"\n'), OK]
    with pytest.raises(ScpiError, match="-222"):
        _exchange(pairs, lambda psu: psu.set_voltage(45.0))
    with served("scpi", "pty") as rig:
        check_error_queue(rig, "SYST:ERR?", "FROB 1", '+0,"No error"')


def test_scpi_version() -> None:
    with served("scpi", "pty") as rig:
        assert rig.ask("SYST:VERS?") == "1999.0"


def test_status_registers() -> None:
    with served("scpi", "pty") as rig:
        assert rig.ask("STAT:QUES:COND?") == "+0"
        rig.send("STAT:QUES:ENAB 1;:STAT:OPER:ENAB 256")  # `:` back to the root
        assert (rig.ask("STAT:QUES:ENAB?"), rig.ask("STAT:OPER:ENAB?")) == ("+1", "+256")
        part = rig.world.sockets[1].part
        assert part is not None
        part.shorted = True  # the bench's supply_short: 5 V would draw 10 A against 0.1 A
        rig.send("VOLT 5;CURR 0.1;OUTP ON")
        assert rig.ask("STAT:QUES:COND?") == "+1"  # constant current: voltage not held
        assert rig.ask("*STB?") == "+8"  # QUES summary
        assert rig.ask("STAT:QUES?") == "+1" and rig.ask("STAT:QUES?") == "+0"
        assert (rig.ask("STAT:OPER?"), rig.ask("STAT:OPER:COND?")) == ("+0", "+0")
        rig.send("STAT:PRES")
        assert (rig.ask("STAT:QUES:ENAB?"), rig.ask("STAT:OPER:ENAB?")) == ("+0", "+0")


def test_levels() -> None:
    _exchange([Pair(b"VOLT 5.250\n"), OK, Pair(b"CURR 0.1000\n"), OK,
               Pair(b"VOLT?\n", b"5.2500\n"), Pair(b"CURR?\n", b"0.1000\n"),
               Pair(b"MEAS:VOLT?\n", b"5.2500\n"), Pair(b"MEAS:CURR?\n", b"0.0100\n")],
              lambda psu: (psu.set_voltage(5.25), psu.set_current_limit(0.1),
                           _forget_and_check(psu)))
    with served("scpi", "pty") as rig:
        rig.send("VOLT 5.25;CURR 0.2")
        assert (rig.ask("VOLT?"), rig.ask("CURR?")) == ("5.2500", "0.2000")
        rig.send("VOLT 31")
        rig.send("CURR 3.2")
        assert rig.errors() == ['-222,"Data out of range"'] * 2
        assert (rig.ask("VOLT?"), rig.ask("CURR?")) == ("5.2500", "0.2000")


def _forget_and_check(psu: ScpiSupply) -> None:
    psu._voltage_set_v = psu._current_limit_a = None  # read back from the instrument
    psu.check_current_limit()


def test_range_queries() -> None:
    _exchange([Pair(b"*IDN?\n", b"Maker,Model-1,SN1,1.0\n"), Pair(b"VOLT? MAX\n", b"30.0000\n"),
               Pair(b"CURR? MAX\n", b"3.0000\n")],
              lambda psu: _range_is(psu, 30.0, 3.0))
    with served("scpi", "pty") as rig:
        assert (rig.ask("VOLT? MAX"), rig.ask("CURR? MAX")) == ("30.0000", "3.0000")
        assert (rig.ask("VOLT? MIN"), rig.ask("CURR? MIN")) == ("0.0000", "0.0000")


def _range_is(psu: ScpiSupply, volts: float, amps: float) -> None:
    found = psu.output_range()
    assert found is not None and (found.high_v, found.max_a) == (volts, amps)


def test_output_and_measure() -> None:
    _exchange([Pair(b"OUTP ON\n"), OK, Pair(b"OUTP?\n", b"1\n"),
               Pair(b"MEAS:VOLT?\n", b"5.0001\n"), Pair(b"MEAS:CURR?\n", b"0.025000\n"),
               Pair(b"OUTP OFF\n"), OK, Pair(b"OUTP?\n", b"0\n")],
              lambda psu: (psu.output(True), psu.output_is_on(), psu.measure_voltage(),
                           psu.measure_current(), psu.output(False), psu.output_is_on()))
    with served("scpi", "pty") as rig:
        rig.send("VOLT 5;CURR 0.1;OUTP ON")
        assert rig.ask("OUTP?") == "1"
        assert float(rig.ask("MEAS:VOLT?")) == pytest.approx(5.0, abs=2e-3)
        amps = float(rig.ask("MEAS:CURR?"))  # the part's draw, as the world has it
        assert amps > 0.005 and amps == pytest.approx(rig.world.supply.truth()["amps"], abs=1e-4)
        rig.send("OUTP OFF")
        assert (rig.ask("OUTP?"), float(rig.ask("MEAS:VOLT?"))) == ("0", 0.0)
