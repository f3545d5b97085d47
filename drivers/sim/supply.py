"""The DC supply in the world: constant-voltage / constant-current crossover, and the generic
SCPI supply the bench's pseudo-terminal serves (the `supply.scpi` family).

The load is the fixture's parts, each close to a resistor drawing its nominal current at
5 V; a shorted part is a fraction of an ohm. When the load would draw more than the current
limit, the supply goes constant-current and the output voltage collapses.

`GenericScpiSupply` is a single-output supply as SCPI-1999 describes one (vol. 2: SOURce,
OUTPut, MEASure; vol. 1 4.2.1: the required commands, with IEEE 488.2's common commands in
`drivers.sim.ieee488`): no maker's product, and its *IDN? says so (the sim config's
`supply:` manufacturer and model).
"""

from __future__ import annotations

from collections import deque
from typing import Any

import numpy as np

from drivers.sim.config import SupplyConfig
from drivers.sim.ieee488 import ScpiInstrument
from drivers.sim.scpi_syntax import (
    ILLEGAL_VALUE,
    UNDEFINED_HEADER,
    Unit,
    boolean,
    keyword,
    match,
    number,
)

CC_BIT = 1  # QUEStionable bit 0 (VOLTage): the output cannot hold its set voltage (CC)


class SupplyModel:
    """One output's electrical state; its range (`max_v`, `max_a`) is the sim config's, or
    the output's of the model a LAN twin serves."""

    def __init__(self, config: SupplyConfig, rng: np.random.Generator) -> None:
        self.cfg = config
        self._rng = rng
        self.max_v = config.max_voltage_v
        self.max_a = config.max_current_a
        self.load_siemens = 0.0
        self.reset()
        self.scpi = GenericScpiSupply(self)

    @property
    def errors(self) -> deque[tuple[int, str]]:
        """The generic SCPI supply's error queue."""
        return self.scpi.status.errors

    def reset(self) -> None:
        self.voltage_set_v = 0.0
        self.current_limit_a = 0.1
        self.output_on = False

    def handle(self, line: str) -> str | None:
        """One SCPI message to the generic supply -> its response, or None."""
        return self.scpi.handle(line)

    # ------------------------------------------------------------ electrical

    def operating_point(self) -> tuple[float, float, str]:
        """(volts, amps, 'CV'|'CC'|'OFF') at the present load."""
        if not self.output_on:
            return 0.0, 0.0, "OFF"
        g = self.load_siemens
        if g * self.voltage_set_v <= self.current_limit_a:
            return self.voltage_set_v, g * self.voltage_set_v, "CV"
        return self.current_limit_a / g, self.current_limit_a, "CC"

    def output_v(self) -> float:
        return self.operating_point()[0]

    def measured_v(self) -> float:
        v = self.operating_point()[0]
        return max(0.0, v + (self._rng.normal(0.0, 2e-4) if self.output_on else 0.0))

    def measured_a(self) -> float:
        i = self.operating_point()[1]
        return max(0.0, i + (self._rng.normal(0.0, 2e-6) if self.output_on else 0.0))

    def truth(self) -> dict[str, Any]:
        v, i, mode = self.operating_point()
        return {
            "output": self.output_on,
            "voltage_set_v": self.voltage_set_v,
            "current_limit_a": self.current_limit_a,
            "volts": v,
            "amps": i,
            "mode": mode,
            "load_siemens": self.load_siemens,
            "error_queue": len(self.errors),
        }


class GenericScpiSupply(ScpiInstrument):
    """`VOLT 5`, `CURR 0.1`, `OUTP ON`, `MEAS:VOLT?`, `VOLT? MAX`...: SCPI-1999's DC source."""

    signed = True
    self_test = "+0"

    def __init__(self, output: SupplyModel) -> None:
        super().__init__()
        self.output = output

    @property
    def identity(self) -> str:
        c = self.output.cfg
        return f"{c.manufacturer},{c.model},{c.serial},{c.firmware}"

    def reset(self) -> None:
        self.output.reset()

    def conditions(self) -> tuple[int, int]:
        return (CC_BIT if self.output.operating_point()[2] == "CC" else 0), 0

    def command(self, unit: Unit) -> str | None:
        out = self.output
        for word, unit_max, attr, digits in (("VOLTage", out.max_v, "voltage_set_v", 4),
                                             ("CURRent", out.max_a, "current_limit_a", 4)):
            if match(unit, f"[SOURce]:{word}[:LEVel][:IMMediate][:AMPLitude]") is not None:
                if unit.query:
                    (which,) = unit.arity(0, 1) or ("",)
                    kind = keyword(which) if which else None
                    if which and kind not in ("MIN", "MAX"):
                        raise ILLEGAL_VALUE
                    value = {"MIN": 0.0, "MAX": unit_max}.get(kind or "", getattr(out, attr))
                    return f"{value:.{digits}f}"
                setattr(out, attr, number(unit.arity(1)[0], 0.0, unit_max, 0.0))
                return None
        if match(unit, "OUTPut[:STATe]") is not None:
            if unit.query:
                unit.arity(0)
                return "1" if out.output_on else "0"
            out.output_on = boolean(unit.arity(1)[0])
            return None
        if match(unit, "MEASure[:SCALar]:VOLTage[:DC]", query=True) is not None:
            unit.arity(0)
            return f"{out.measured_v():.4f}"
        if match(unit, "MEASure[:SCALar]:CURRent[:DC]", query=True) is not None:
            unit.arity(0)
            return f"{out.measured_a():.6f}"
        raise UNDEFINED_HEADER


class SupplyOutputs:
    """The outputs of a multi-output supply: the world's supply on `channel` (the parts'),
    the others unloaded; each output's range (max V, max A) is the model's."""

    def __init__(
        self, main: SupplyModel, channel: int, ranges: dict[int, tuple[float, float]]
    ) -> None:
        if channel not in ranges:
            raise ValueError(f"the part's supply channel must be one of {sorted(ranges)}, "
                             f"not {channel}")
        self.main = main
        self.channel = channel
        self._models: dict[int, SupplyModel] = {}
        for n, (max_v, max_a) in ranges.items():
            model = main if n == channel else SupplyModel(main.cfg, np.random.default_rng(n))
            model.max_v, model.max_a = max_v, max_a
            self._models[n] = model

    @property
    def numbers(self) -> list[int]:
        return sorted(self._models)

    def model(self, channel: int) -> SupplyModel:
        """Output `channel`; -224 Illegal parameter value if the supply has no such output."""
        found = self._models.get(channel)
        if found is None:
            raise ILLEGAL_VALUE
        return found

    def reset(self) -> None:
        for model in self._models.values():
            model.reset()
