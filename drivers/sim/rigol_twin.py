"""The Rigol DP832 as Rigol's DP800 Series Programming Guide describes it, for the simulated
bench (the `supply.rigol-dp800` twin).

Three channels, rated CH1 and CH2 30 V / 3 A, CH3 5 V / 3 A; each takes settings up to its
programming range (32 V / 3.2 A, 5.3 V / 3.2 A: the guide's :APPLy ranges), beyond which it
answers -222 Data out of range. Commands name their channel (`:OUTP CH2,ON`, `:MEAS:ALL? CH2`,
`:APPL CH2,5,0.1`, `:SOUR2:VOLT 5`) or act on the one `:INST CH2` / `:INST:NSEL 2` selected.
Over-voltage and over-current protection (`:OUTP:OVP`, `:OUTP:OCP`) trip the channel off and
latch an alarm until `:OUTP:OVP:CLEAR`. Replies in Rigol's forms: `ON`/`OFF`, `YES`/`NO`,
`CH1:30V/3A,5.000,0.100`, measurements `5.0114,0.0000,0.000`, NR1 without a sign.
"""

from __future__ import annotations

from dataclasses import dataclass

from drivers.sim.ieee488 import ScpiInstrument
from drivers.sim.scpi_syntax import (
    ILLEGAL_VALUE,
    PARAMETER_NOT_ALLOWED,
    UNDEFINED_HEADER,
    Unit,
    boolean,
    integer,
    keyword,
    match,
    number,
)
from drivers.sim.supply import SupplyModel, SupplyOutputs

MODEL = "DP832"
FIRMWARE = "00.01.16"
RATINGS = {1: "30V/3A", 2: "30V/3A", 3: "5V/3A"}
RANGES = {1: (32.0, 3.2), 2: (32.0, 3.2), 3: (5.3, 3.2)}  # programming ranges, V and A
PROTECTION_RANGES = {1: (33.0, 3.3), 2: (33.0, 3.3), 3: (5.5, 3.3)}  # OVP V, OCP A


@dataclass
class Protection:
    """One channel's OVP or OCP: on, its value, tripped."""

    on: bool
    value: float
    tripped: bool = False


class RigolDP832(ScpiInstrument):
    """The DP832's SCPI over its channels (`SupplyOutputs`)."""

    signed = False
    self_test = "TopBoard:PASS,BottomBoard:PASS,Fan:PASS"

    def __init__(self, outputs: SupplyOutputs, serial: str) -> None:
        super().__init__()
        self.outputs = outputs
        self.serial = serial
        self.selected = 1
        self.model = MODEL
        self.protection: dict[tuple[str, int], Protection] = {}
        self.reset()

    @property
    def identity(self) -> str:
        return f"RIGOL TECHNOLOGIES,{self.model},{self.serial},{FIRMWARE}"

    def reset(self) -> None:
        self.outputs.reset()
        self.selected = 1
        for n, (ovp_v, ocp_a) in PROTECTION_RANGES.items():
            self.protection[("OVP", n)] = Protection(False, ovp_v)
            self.protection[("OCP", n)] = Protection(False, ocp_a)

    def handle(self, message: str) -> str | None:
        reply = super().handle(message)
        self._trip()
        return reply

    def command(self, unit: Unit) -> str | None:
        if match(unit, "APPLy") is not None:
            return self._apply_query(unit) if unit.query else self._apply(unit)
        if match(unit, "INSTrument[:SELect]") is not None:
            return self._select(unit, by_name=True)
        if match(unit, "INSTrument:NSELect") is not None:
            return self._select(unit, by_name=False)
        for word, index in (("VOLTage", 0), ("CURRent", 1)):
            found = match(unit, f"[SOURce#]:{word}[:LEVel][:IMMediate][:AMPLitude]")
            if found is not None:
                return self._level(unit, found[0] or self.selected, index)
        if match(unit, "OUTPut[:STATe]") is not None:
            return self._output(unit)
        for pattern in ("OUTPut:MODE", "OUTPut:CVCC"):
            if match(unit, pattern, query=True) is not None:
                mode = self._model(self._named(unit.arity(0, 1))).operating_point()[2]
                return "CC" if mode == "CC" else "CV"
        for kind in ("OVP", "OCP"):
            reply = self._protection(unit, kind)
            if reply is not False:
                return reply if isinstance(reply, str) else None
        return self._measure(unit)

    # ------------------------------------------------------------ channels

    def _channel(self, text: str) -> int:
        word = text.strip().upper()
        if not (word.startswith("CH") and word[2:].isdigit()):
            raise ILLEGAL_VALUE
        channel = int(word[2:])
        self.outputs.model(channel)
        return channel

    def _named(self, params: tuple[str, ...]) -> int:
        """The channel a query's optional `CHn` names, else the selected one."""
        return self._channel(params[0]) if params else self.selected

    def _model(self, channel: int) -> SupplyModel:
        return self.outputs.model(channel)

    def _select(self, unit: Unit, *, by_name: bool) -> str | None:
        if unit.query:
            unit.arity(0)
            return f"CH{self.selected}" if by_name else str(self.selected)
        text = unit.arity(1)[0]
        channel = self._channel(text) if by_name else integer(text, 1, 3)
        self.outputs.model(channel)
        self.selected = channel
        return None

    # ------------------------------------------------------------ levels and outputs

    def _apply(self, unit: Unit) -> str | None:
        params = unit.arity(1, 3)
        channel = self.selected
        if params[0].strip().upper().startswith("CH"):
            channel, params = self._channel(params[0]), params[1:]
        if len(params) > 2:
            raise PARAMETER_NOT_ALLOWED
        model = self._model(channel)
        volts = number(params[0], 0.0, model.max_v) if params else model.voltage_set_v
        amps = number(params[1], 0.0, model.max_a) if len(params) > 1 else model.current_limit_a
        model.voltage_set_v, model.current_limit_a = volts, amps
        return None

    def _apply_query(self, unit: Unit) -> str:
        params = unit.arity(0, 2)
        channel = self._channel(params[0]) if params else self.selected
        model = self._model(channel)
        if len(params) == 2:
            what = params[1].strip().upper()
            if what in ("VOLT", "VOLTAGE"):
                return f"{model.voltage_set_v:.3f}"
            if what in ("CURR", "CURRENT"):
                return f"{model.current_limit_a:.3f}"
            raise ILLEGAL_VALUE
        levels = f"{model.voltage_set_v:.3f},{model.current_limit_a:.3f}"
        return f"CH{channel}:{RATINGS[channel]},{levels}"

    def _level(self, unit: Unit, channel: int, index: int) -> str | None:
        model = self._model(channel)
        high = (model.max_v, model.max_a)[index]
        attr = ("voltage_set_v", "current_limit_a")[index]
        if unit.query:
            params = unit.arity(0, 1)
            kind = keyword(params[0]) if params else None
            if params and kind not in ("MIN", "MAX"):
                raise ILLEGAL_VALUE
            value = {"MIN": 0.0, "MAX": high}.get(kind or "", getattr(model, attr))
            return f"{value:.3f}"
        setattr(model, attr, number(unit.arity(1)[0], 0.0, high))
        return None

    def _output(self, unit: Unit) -> str | None:
        if unit.query:
            return "ON" if self._model(self._named(unit.arity(0, 1))).output_on else "OFF"
        params = unit.arity(1, 2)
        channel = self._channel(params[0]) if len(params) == 2 else self.selected
        on = boolean(params[-1])
        if on and any(self.protection[(k, channel)].tripped for k in ("OVP", "OCP")):
            return None  # a tripped channel stays off until its alarm is cleared
        self._model(channel).output_on = on
        return None

    def _measure(self, unit: Unit) -> str:
        for word, fmt in (("[:VOLTage]", "{v:.4f}"), (":CURRent", "{i:.4f}"),
                          (":POWEr", "{p:.3f}"), (":ALL", "{v:.4f},{i:.4f},{p:.3f}")):
            if match(unit, f"MEASure{word}[:DC]", query=True) is not None:
                model = self._model(self._named(unit.arity(0, 1)))
                v, i = model.measured_v(), model.measured_a()
                return fmt.format(v=v, i=i, p=v * i)
        raise UNDEFINED_HEADER

    # ------------------------------------------------------------ protection

    def _protection(self, unit: Unit, kind: str) -> str | None | bool:
        """`:OUTP:OVP...` / `:OUTP:OCP...`; False when `unit` is none of them."""
        if match(unit, f"OUTPut:{kind}[:STATe]") is not None:
            if unit.query:
                return "ON" if self._guard(kind, unit.arity(0, 1)).on else "OFF"
            params = unit.arity(1, 2)
            self._guard(kind, params[:-1]).on = boolean(params[-1])
            return None
        if match(unit, f"OUTPut:{kind}:VALue") is not None:
            return self._protection_value(unit, kind)
        for word in ("ALARm", "QUEStion"):
            if match(unit, f"OUTPut:{kind}:{word}", query=True) is not None:
                return "YES" if self._guard(kind, unit.arity(0, 1)).tripped else "NO"
        if match(unit, f"OUTPut:{kind}:CLEar", query=False) is not None:
            self._guard(kind, unit.arity(0, 1)).tripped = False
            return None
        return False

    def _guard(self, kind: str, params: tuple[str, ...]) -> Protection:
        return self.protection[(kind, self._named(params))]

    def _protection_value(self, unit: Unit, kind: str) -> str | None:
        """`:OUTP:OVP:VAL [CHn,]<v>` (0.01 V up to the channel's limit; OCP from 0.001 A),
        `:OUTP:OVP:VAL? [CHn][,MIN|MAX]`."""
        low = 0.01 if kind == "OVP" else 0.001
        if unit.query:
            params = list(unit.arity(0, 2))
            limit = keyword(params[-1]) if params else None
            if limit is not None:
                params.pop()
            channel = self._named(tuple(params))
            high = PROTECTION_RANGES[channel][0 if kind == "OVP" else 1]
            now = self.protection[(kind, channel)].value
            value = {"MIN": low, "MAX": high}.get(limit or "", now)
            return f"{value:.3f}"
        given = unit.arity(1, 2)
        channel = self._named(given[:-1])
        high = PROTECTION_RANGES[channel][0 if kind == "OVP" else 1]
        self.protection[(kind, channel)].value = number(given[-1], low, high)
        return None

    def _trip(self) -> None:
        """A protection that is on trips its channel off when the output passes its value."""
        for (kind, channel), guard in self.protection.items():
            model = self._model(channel)
            if not (guard.on and model.output_on):
                continue
            volts, amps, _ = model.operating_point()
            if (volts if kind == "OVP" else amps) >= guard.value:
                guard.tripped = True
                model.output_on = False
