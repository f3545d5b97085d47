"""The Keysight E36312A as Keysight's E36300 Series Programming Guide describes it, for the
simulated bench (the `supply.keysight-e36300` twin).

Three outputs, each with its own range (E36312A: output 1 0-6 V / 0-5 A, outputs 2 and 3
0-25 V / 0-1 A; a value beyond it is -222 Data out of range and changes nothing). A command
names its outputs with a channel list (`VOLT 5,(@2)`, `MEAS:VOLT? (@1:3)`); without one it
acts on the output `INST:SEL CH2` / `INST:NSEL 2` selected (output 1 after *RST). `APPL CH2,5,0.1`
sets an output's voltage and current at once, `APPL? CH2` reads them back. Numbers are answered
in NR3 (`+5.00000000E+00`), output states as 1/0, NR1 with a sign (`+0`).
"""

from __future__ import annotations

from drivers.sim.ieee488 import ScpiInstrument
from drivers.sim.scpi_syntax import (
    ILLEGAL_VALUE,
    MISSING_PARAMETER,
    PARAMETER_NOT_ALLOWED,
    UNDEFINED_HEADER,
    Unit,
    boolean,
    channel_list,
    integer,
    keyword,
    match,
    number,
)
from drivers.sim.supply import SupplyModel, SupplyOutputs

MODEL = "E36312A"
# the E36312A's outputs, (V, A): E36300 Series data sheet and programming guide
RANGES = {1: (6.0, 5.0), 2: (25.0, 1.0), 3: (25.0, 1.0)}
_NAMES = {"CH1": 1, "CH2": 2, "CH3": 3, "P6V": 1, "P25V": 2, "N25V": 3}
_LEVELS = {"VOLTage": ("voltage_set_v", 0), "CURRent": ("current_limit_a", 1)}


def nr3(value: float) -> str:
    return f"{value:+.8E}"


class KeysightE36312A(ScpiInstrument):
    """The E36312A's SCPI over its outputs (`SupplyOutputs`)."""

    signed = True
    self_test = "+0"

    def __init__(self, outputs: SupplyOutputs, serial: str, firmware: str) -> None:
        super().__init__()
        self.outputs = outputs
        self.serial, self.firmware = serial, firmware
        self.selected = 1
        self.model = MODEL

    @property
    def identity(self) -> str:
        return f"Keysight Technologies,{self.model},{self.serial},{self.firmware}"

    def reset(self) -> None:
        self.outputs.reset()
        self.selected = 1

    def command(self, unit: Unit) -> str | None:
        if match(unit, "APPLy") is not None:
            return self._apply_query(unit) if unit.query else self._apply(unit)
        if match(unit, "INSTrument[:SELect]") is not None:
            return self._select(unit, by_name=True)
        if match(unit, "INSTrument:NSELect") is not None:
            return self._select(unit, by_name=False)
        for word in _LEVELS:
            if match(unit, f"[SOURce]:{word}[:LEVel][:IMMediate][:AMPLitude]") is not None:
                return self._level(unit, word)
        if match(unit, "OUTPut[:STATe]") is not None:
            return self._output(unit)
        for word, read in (("VOLTage", SupplyModel.measured_v),
                           ("CURRent", SupplyModel.measured_a)):
            if match(unit, f"MEASure[:SCALar]:{word}[:DC]", query=True) is not None:
                values, channels = self._channels(unit.params)
                if values:
                    raise PARAMETER_NOT_ALLOWED
                return ",".join(nr3(read(self.outputs.model(c))) for c in channels)
        raise UNDEFINED_HEADER

    # ------------------------------------------------------------ the commands

    def _channels(self, params: tuple[str, ...]) -> tuple[tuple[str, ...], list[int]]:
        """(the other parameters, the outputs named by a trailing channel list or else the
        selected output); every output must exist (-224)."""
        if params and params[-1].startswith("("):
            channels = channel_list(params[-1])
            params = params[:-1]
        else:
            channels = [self.selected]
        for c in channels:
            self.outputs.model(c)
        return params, channels

    def _output_named(self, text: str) -> int:
        found = _NAMES.get(text.strip().upper())
        if found is None:
            raise ILLEGAL_VALUE
        return found

    def _apply(self, unit: Unit) -> str | None:
        name, *levels = unit.arity(1, 3)
        model = self.outputs.model(self._output_named(name))
        volts = number(levels[0], 0.0, model.max_v, 0.0) if levels else model.voltage_set_v
        amps = (number(levels[1], 0.0, model.max_a, model.max_a) if len(levels) > 1
                else model.current_limit_a)
        model.voltage_set_v, model.current_limit_a = volts, amps
        return None

    def _apply_query(self, unit: Unit) -> str:
        model = self.outputs.model(self._output_named(unit.arity(1)[0]))
        return f"{nr3(model.voltage_set_v)},{nr3(model.current_limit_a)}"

    def _select(self, unit: Unit, *, by_name: bool) -> str | None:
        if unit.query:
            unit.arity(0)
            return f"CH{self.selected}" if by_name else self.nr1(self.selected)
        text = unit.arity(1)[0]
        channel = self._output_named(text) if by_name else integer(text, 1, 3)
        self.outputs.model(channel)
        self.selected = channel
        return None

    def _level(self, unit: Unit, word: str) -> str | None:
        attr, index = _LEVELS[word]
        values, channels = self._channels(unit.params)
        models = [self.outputs.model(c) for c in channels]
        if unit.query:
            if len(values) > 1:
                raise PARAMETER_NOT_ALLOWED
            kind = keyword(values[0]) if values else None
            if values and kind not in ("MIN", "MAX"):
                raise ILLEGAL_VALUE
            return ",".join(nr3(_level_of(m, attr, index, kind)) for m in models)
        _one(values)
        new = [number(values[0], 0.0, (m.max_v, m.max_a)[index], 0.0) for m in models]
        for model, value in zip(models, new, strict=True):
            setattr(model, attr, value)
        return None

    def _output(self, unit: Unit) -> str | None:
        values, channels = self._channels(unit.params)
        if unit.query:
            if values:
                raise PARAMETER_NOT_ALLOWED
            return ",".join("1" if self.outputs.model(c).output_on else "0" for c in channels)
        on = boolean(_one(values))
        for c in channels:
            self.outputs.model(c).output_on = on
        return None


def _level_of(model: SupplyModel, attr: str, index: int, kind: str | None) -> float:
    if kind == "MIN":
        return 0.0
    if kind == "MAX":
        return (model.max_v, model.max_a)[index]
    value: float = getattr(model, attr)
    return value


def _one(values: tuple[str, ...]) -> str:
    """The one value a setting takes before its channel list."""
    if not values:
        raise MISSING_PARAMETER
    if len(values) > 1:
        raise PARAMETER_NOT_ALLOWED
    return values[0]
