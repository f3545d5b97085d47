"""The LAN supply twins' command handling, message by message (no socket): each family's
syntax reaches the shared SupplyModel, and what a real unit refuses is queued as its error."""

from __future__ import annotations

import pytest

from drivers.sim.config import SimConfig
from drivers.sim.scpi_lan_twins import KeysightE36300Twin, RigolDp800Twin
from drivers.sim.world import World


@pytest.fixture
def world() -> World:
    return World(SimConfig.model_validate({"parts": [{"socket": 1, "serial": "SIM-C001"}]}), 1.0)


def _errors(twin: KeysightE36300Twin | RigolDp800Twin) -> list[str]:
    out = []
    while (reply := twin.handle("SYST:ERR?")) is not None and reply.lstrip("+")[0] != "0":
        out.append(reply)
    return out


def test_keysight_channel_lists_reach_the_right_output(world: World) -> None:
    twin = KeysightE36300Twin(world, channel=3)
    for line in ("VOLT 5.25,(@3)", "CURR 0.2, (@3)", "OUTP 1,(@3)", "VOLT 4.5,(@1)"):
        assert twin.handle(line) is None
    s = world.supply
    assert (s.voltage_set_v, s.current_limit_a, s.output_on) == (5.25, 0.2, True)
    assert twin.handle("VOLT? (@1)") == "+4.50000000E+00"  # output 1 is its own
    assert twin.handle("OUTP? (@3)") == "1" and twin.handle("OUTP? (@1)") == "0"
    assert float(twin.handle("MEAS:VOLT? (@3)") or "nan") == pytest.approx(5.25, abs=2e-3)
    assert twin.handle("*IDN?") == "Keysight Technologies,E36312A,PS-0001,1.2"
    assert _errors(twin) == []
    twin.handle("*RST")
    assert (s.voltage_set_v, s.output_on) == (0.0, False)
    assert twin.handle("VOLT? (@1)") == "+0.00000000E+00"


def test_keysight_refusals_are_queued(world: World) -> None:
    twin = KeysightE36300Twin(world)
    twin.handle("VOLT 5,(@4)")  # no output 4
    twin.handle("VOLT 10,(@1)")  # beyond output 1's 6 V
    twin.handle("VOLT? 5,(@1)")  # a query with a value
    twin.handle("FROB 1,(@1)")
    assert _errors(twin) == [
        '-224,"Illegal parameter value"',
        '-222,"Data out of range"',
        '-224,"Illegal parameter value"',
        '-113,"Undefined header"',
    ]
    assert world.supply.voltage_set_v == 0.0


def test_rigol_compound_messages_and_channel_arguments(world: World) -> None:
    twin = RigolDp800Twin(world, channel=2)
    assert twin.handle(":INST:NSEL 2;:VOLT 5.000") is None
    assert twin.handle(":INST:NSEL 2; :CURR 0.1500") is None
    assert twin.handle(":OUTP CH2,ON") is None
    s = world.supply
    assert (s.voltage_set_v, s.current_limit_a, s.output_on) == (5.0, 0.15, True)
    assert twin.handle(":OUTP? CH2") == "ON" and twin.handle(":OUTP? CH1") == "OFF"
    assert twin.handle(":APPL? CH2,VOLT") == "5.000"
    assert twin.handle(":APPL? CH2,CURR") == "0.150"
    assert twin.handle(":APPL CH1,3.3,0.5") is None  # output 1, not the part's
    assert twin.handle(":APPL? CH1,VOLT") == "3.300" and s.voltage_set_v == 5.0
    assert twin.handle(":INST:NSEL 1;:VOLT?") == "3.300"
    assert twin.handle(":MEAS:CURR? CH1") == "0.0000"
    assert twin.handle("*IDN?") == "RIGOL TECHNOLOGIES,DP832,PS-0001,00.01.16"
    assert _errors(twin) == []


def test_rigol_refusals_are_queued(world: World) -> None:
    twin = RigolDp800Twin(world)
    twin.handle(":OUTP CH4,ON")
    twin.handle(":INST:NSEL 1;:VOLT 99")
    twin.handle(":VOLT:FROB 1")
    assert _errors(twin) == [
        '-224,"Illegal parameter value"',
        '-222,"Data out of range"',
        '-113,"Undefined header"',
    ]


def test_the_parts_channel_must_exist(world: World) -> None:
    with pytest.raises(ValueError, match=r"\[1, 2, 3\]"):
        KeysightE36300Twin(world, channel=4)
