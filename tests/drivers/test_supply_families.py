"""The three SCPI supply families byte for byte through pyvisa + pyvisa-py, over a real
loopback socket (TCPIP SOCKET) and a real pseudo-terminal (ASRL): the exact messages on the wire,
the error queue after every setting, replies parsed per family, and every fault a typed error."""

from __future__ import annotations

import pytest

from drivers import keysight_e36300, rigol_dp800, supply
from drivers.errors import ProtocolError, ScpiError, SupplyCurrentLimit
from drivers.keysight_e36300 import KeysightE36300Dialect
from drivers.protocols import Supply
from drivers.rigol_dp800 import RigolDp800Dialect
from drivers.supply import ScpiDialect, ScpiSupply
from tests.drivers._scpi_fakes import NO_ERROR, ScriptedScpi
from tests.drivers.expected_protocol import Pair

GENERIC_ERR = b"SYST:ERR?\n"
RIGOL_ERR = b":SYST:ERR?\n"

# family -> (dialect, error query, {operation: exact message})
FAMILIES = {
    "scpi": (ScpiDialect(), GENERIC_ERR, {
        "volt": b"VOLT 5.250\n", "curr": b"CURR 0.1000\n", "on": b"OUTP ON\n",
        "off": b"OUTP OFF\n", "on?": b"OUTP?\n", "mv": b"MEAS:VOLT?\n", "mc": b"MEAS:CURR?\n",
        "v?": b"VOLT?\n", "c?": b"CURR?\n",
    }),
    "keysight-e36300": (KeysightE36300Dialect(2), GENERIC_ERR, {
        "volt": b"VOLT 5.250,(@2)\n", "curr": b"CURR 0.1000,(@2)\n", "on": b"OUTP 1,(@2)\n",
        "off": b"OUTP 0,(@2)\n", "on?": b"OUTP? (@2)\n", "mv": b"MEAS:VOLT? (@2)\n",
        "mc": b"MEAS:CURR? (@2)\n", "v?": b"VOLT? (@2)\n", "c?": b"CURR? (@2)\n",
    }),
    "rigol-dp800": (RigolDp800Dialect(3), RIGOL_ERR, {
        "volt": b":INST:NSEL 3;:VOLT 5.250\n", "curr": b":INST:NSEL 3;:CURR 0.1000\n",
        "on": b":OUTP CH3,ON\n", "off": b":OUTP CH3,OFF\n", "on?": b":OUTP? CH3\n",
        "mv": b":MEAS:VOLT? CH3\n", "mc": b":MEAS:CURR? CH3\n", "v?": b":APPL? CH3,VOLT\n",
        "c?": b":APPL? CH3,CURR\n",
    }),
}  # fmt: skip
# how each family answers (Keysight: NR3 numbers, 1/0; Rigol: fixed point, ON/OFF)
REPLIES = {
    "scpi": {"v": b"5.2498\n", "i": b"0.024000\n", "on": b"1\n", "off": b"0\n",
             "vset": b"5.2500\n", "iset": b"0.1000\n", "err": NO_ERROR},
    "keysight-e36300": {"v": b"+5.24980000E+00\n", "i": b"+2.40000000E-02\n", "on": b"1\n",
                        "off": b"0\n", "vset": b"+5.25000000E+00\n", "iset": b"+1.00000000E-01\n",
                        "err": NO_ERROR},
    "rigol-dp800": {"v": b"5.2498\n", "i": b"0.0240\n", "on": b"ON\n", "off": b"OFF\n",
                    "vset": b"5.250\n", "iset": b"0.1000\n", "err": b'0,"No error"\n'},
}  # fmt: skip
KINDS = ["tcp", "pty"]


def _open(fake: ScriptedScpi, dialect: ScpiDialect) -> ScpiSupply:
    return ScpiSupply.open(fake.resource, timeout_s=0.5, dialect=dialect)


@pytest.fixture(params=list(FAMILIES))
def family(request: pytest.FixtureRequest) -> str:
    return str(request.param)


@pytest.mark.parametrize("kind", KINDS)
def test_settings_queries_and_the_error_queue_exact_bytes(family: str, kind: str) -> None:
    dialect, err, cmd = FAMILIES[family]
    r = REPLIES[family]
    ok = Pair(err, r["err"])
    fake = ScriptedScpi([
        Pair(b"*IDN?\n", b"Maker,Model-9,SN123,1.0\r\n"),
        Pair(cmd["volt"]), ok, Pair(cmd["curr"]), ok, Pair(cmd["on"]), ok,
        Pair(cmd["on?"], r["on"]), Pair(cmd["mv"], r["v"]), Pair(cmd["mc"], r["i"]),
        Pair(cmd["off"]), ok, Pair(cmd["on?"], r["off"]),
        Pair(b"*RST\n"), ok,
        Pair(cmd["v?"], r["vset"]), Pair(cmd["c?"], r["iset"]),
        Pair(cmd["mv"], r["v"]), Pair(cmd["mc"], r["i"]),
        Pair(cmd["off"]), ok,
    ], kind)
    psu = _open(fake, dialect)
    try:
        assert psu.identify().model == "Model-9"
        psu.set_voltage(5.25)
        psu.set_current_limit(0.1)
        psu.output(True)
        assert psu.output_is_on() is True
        assert psu.measure_voltage() == pytest.approx(5.2498)
        assert psu.measure_current() == pytest.approx(0.024)
        psu.output(False)
        assert psu.output_is_on() is False
        psu.reset()  # forgets the set levels: the current check reads them back
        assert psu.check_current_limit() == pytest.approx((5.2498, 0.024))
        psu.safe_state()
    finally:
        psu.close()
        fake.close()
    fake.assert_done()


def test_refused_setting_is_scpi_error_with_the_code_and_the_queue_drained(family: str) -> None:
    dialect, err, cmd = FAMILIES[family]
    fake = ScriptedScpi([
        Pair(cmd["volt"]),
        Pair(err, b'-222,"Data out of range"\n'),
        Pair(err, b'-221,"Settings conflict"\n'),
        Pair(err, REPLIES[family]["err"]),
    ])
    psu = _open(fake, dialect)
    try:
        with pytest.raises(ScpiError, match=r"rejected .*-222 Data out of range.*1 more") as info:
            psu.set_voltage(5.25)
        assert info.value.code == -222
    finally:
        psu.close()
        fake.close()
    fake.assert_done()


def test_shorted_part_is_supply_current_limit(family: str) -> None:
    dialect, err, cmd = FAMILIES[family]
    ok = Pair(err, REPLIES[family]["err"])
    volts = b"+3.10000000E-01\n" if family == "keysight-e36300" else b"0.3100\n"
    fake = ScriptedScpi([
        Pair(cmd["volt"]), ok, Pair(cmd["curr"]), ok,
        Pair(cmd["mv"], volts), Pair(cmd["mc"], b"0.099990\n"),
    ])
    psu = _open(fake, dialect)
    try:
        psu.set_voltage(5.25)
        psu.set_current_limit(0.1)
        with pytest.raises(SupplyCurrentLimit, match="shorted"):
            psu.check_current_limit()
    finally:
        psu.close()
        fake.close()
    fake.assert_done()


def test_output_reply_that_is_neither_on_nor_off_is_a_protocol_error(family: str) -> None:
    dialect, _, cmd = FAMILIES[family]
    fake = ScriptedScpi([Pair(cmd["on?"], b"MAYBE\n"), Pair(cmd["mv"], b"\xff\xfe\n")])
    psu = _open(fake, dialect)
    try:
        with pytest.raises(ProtocolError, match="not 1/ON or 0/OFF"):
            psu.output_is_on()
        with pytest.raises(ProtocolError, match="not a number"):
            psu.measure_voltage()
    finally:
        psu.close()
        fake.close()
    fake.assert_done()


# ---------------------------------------------------------------- settings and factories

MODULES = {"scpi": supply, "keysight-e36300": keysight_e36300, "rigol-dp800": rigol_dp800}


def test_factory_validates_connects_and_checks_the_expected_model(family: str) -> None:
    module = MODULES[family]
    err = FAMILIES[family][1]
    extra = {} if family == "scpi" else {"channel": 2}
    fake = ScriptedScpi([Pair(b"*IDN?\n", b"Keysight Technologies,E36312A,MY1,2.1\n")])
    psu = module.factory({"address": fake.resource, "expected_model": "E363", **extra})
    try:
        assert isinstance(psu, Supply)
        if family != "scpi":
            assert psu.dialect.channel == 2
    finally:
        psu.close()
        fake.close()
    fake.assert_done()
    wrong = ScriptedScpi([Pair(b"*IDN?\n", b"RIGOL TECHNOLOGIES,DP832,DP8C1,00.01.16\n")])
    try:
        with pytest.raises(ProtocolError, match="not the expected 'E363'"):
            module.factory({"address": wrong.resource, "expected_model": "E363"})
    finally:
        wrong.close()
    assert err  # every family has an error query


@pytest.mark.parametrize(
    "settings, field",
    [
        ({"address": "/dev/ttyUSB0", "colour": "red"}, "colour"),
        ({"address": "not an address"}, "address"),
        ({"address": "/dev/ttyUSB0", "timeout_s": float("nan")}, "timeout_s"),
        ({"address": "/dev/ttyUSB0", "timeout_s": 0}, "timeout_s"),
        ({}, "address"),
    ],
)
def test_settings_refuse_bad_entries(family: str, settings: dict, field: str) -> None:
    from pydantic import ValidationError

    with pytest.raises(ValidationError, match=field):
        MODULES[family].Settings.model_validate(settings)


@pytest.mark.parametrize("module", [keysight_e36300, rigol_dp800])
@pytest.mark.parametrize("channel", [0, 4])
def test_channel_must_exist(module: object, channel: int) -> None:
    from pydantic import ValidationError

    with pytest.raises(ValidationError, match="channel"):
        module.Settings.model_validate({"address": "TCPIP::h::5025::SOCKET", "channel": channel})


def test_station_yaml_serial_form_is_accepted_by_the_scpi_family() -> None:
    s = supply.Settings.model_validate({"address": "/dev/ttyUSB0", "baud": 115200})
    assert (s.address, s.baud, s.timeout_s) == ("/dev/ttyUSB0", 115200, 1.0)


def test_reconnect_gets_through_to_a_dropped_lan_supply_with_a_longer_timeout() -> None:
    """Issue 25 finding 13: the supply reconnects (the safe-state pass's way through to a slow
    or re-plugged supply), against the Keysight LAN twin."""
    from drivers.errors import ConnectionLost
    from drivers.protocols import Reconnectable
    from drivers.sim.scpi_lan_twins import KeysightE36300Twin
    from tests.drivers._chamber_twin_thread import TwinThread

    with TwinThread(KeysightE36300Twin) as tt:
        psu = keysight_e36300.factory({"address": tt.endpoint, "timeout_s": 0.5})
        try:
            assert isinstance(psu, Reconnectable)
            psu.output(True)
            tt.run(tt.twin.drop())
            with pytest.raises(ConnectionLost):
                psu.output_is_on()
            with pytest.raises(ConnectionLost):  # refused while dropped
                psu.reconnect()
            tt.run(tt.twin.restore())
            tt.twin.delay_s = 0.8  # slower than the configured 0.5 s
            with pytest.raises(ConnectionLost):  # the dead link stays dead until reconnect
                psu.output_is_on()
            psu.reconnect(timeout_s=3.0)
            assert psu.output_is_on() is True  # the world's supply kept its state
            psu.safe_state()
            assert psu.check_safe().safe and not tt.world.supply.output_on
        finally:
            psu.close()
    given = ScpiSupply(type("Given", (), {"instrument": "psu", "close": lambda self: None})())
    with pytest.raises(ConnectionLost, match="cannot reconnect"):
        given.reconnect()  # a transport handed in: nothing to reopen it with


def test_a_reconnect_that_reaches_another_device_commands_nothing() -> None:
    """CI finding: a station whose bench died reconnected by address to a pseudo-terminal
    number the kernel had given to another bench, and commanded that bench. A re-enumerated
    USB adapter does the same on a real line. After a reconnect the supply commands nothing
    until *IDN? names the supply first identified; the safe-state pass then stops retrying."""
    from drivers.errors import ConnectionLost, WrongInstrument
    from drivers.sim.scpi_lan_twins import KeysightE36300Twin
    from tests.drivers._chamber_twin_thread import TwinThread

    with TwinThread(KeysightE36300Twin) as tt:
        heard: list[str] = []
        handle = tt.twin.handle

        def listening(line: str) -> str | None:
            heard.append(line)
            return handle(line)

        tt.twin.handle = listening  # type: ignore[method-assign]
        psu = keysight_e36300.factory({"address": tt.endpoint, "timeout_s": 0.5})
        try:
            first = psu.identify()
            psu.reconnect()  # the same supply: no complaint, and it still obeys
            psu.output(False)
            tt.twin.instrument.model = "E36313A"  # type: ignore[attr-defined]  # the address now leads to another instrument
            heard.clear()
            with pytest.raises(WrongInstrument, match="E36313A.*not the.*E36312A.*nothing was"):
                psu.reconnect()
            assert heard == ["*IDN?"], heard  # asked who it is, commanded nothing
            with pytest.raises(ConnectionLost):  # and the port is closed again
                psu.output(True)
            assert heard == ["*IDN?"] and first.model == "E36312A"
        finally:
            psu.close()
