"""The DC supply in the world: constant-voltage / constant-current crossover, and its SCPI.

The load is the fixture's parts, each close to a resistor drawing its nominal current at
5 V; a shorted part is a fraction of an ohm. When the load would draw more than the current
limit, the supply goes constant-current and the output voltage collapses.
"""

from __future__ import annotations

import re
from collections import deque
from typing import Any

import numpy as np

from drivers.sim.config import SupplyConfig

_NUMBER = r"([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)"


class SupplyModel:
    def __init__(self, config: SupplyConfig, rng: np.random.Generator) -> None:
        self.cfg = config
        self._rng = rng
        self.errors: deque[tuple[int, str]] = deque(maxlen=16)
        self.load_siemens = 0.0
        self.reset()

    def reset(self) -> None:
        self.voltage_set_v = 0.0
        self.current_limit_a = 0.1
        self.output_on = False

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

    # ------------------------------------------------------------ SCPI

    def handle(self, line: str) -> str | None:
        """One SCPI command line -> the reply line, or None for a setting."""
        cmd = line.strip()
        if not cmd:
            return None
        upper = cmd.upper()
        if upper == "*IDN?":
            c = self.cfg
            return f"{c.manufacturer},{c.model},{c.serial},{c.firmware}"
        if upper == "*RST":
            self.reset()
            return None
        if upper in ("OUTP?", "OUTPUT?"):
            return "1" if self.output_on else "0"
        if upper in ("MEAS:VOLT?", "MEASURE:VOLTAGE?"):
            v, _, _ = self.operating_point()
            noise = self._rng.normal(0.0, 2e-4) if self.output_on else 0.0
            return f"{max(0.0, v + noise):.4f}"
        if upper in ("MEAS:CURR?", "MEASURE:CURRENT?"):
            _, i, _ = self.operating_point()
            noise = self._rng.normal(0.0, 2e-6) if self.output_on else 0.0
            return f"{max(0.0, i + noise):.6f}"
        if upper in ("VOLT?", "VOLTAGE?"):
            return f"{self.voltage_set_v:.4f}"
        if upper in ("CURR?", "CURRENT?"):
            return f"{self.current_limit_a:.4f}"
        if upper in ("SYST:ERR?", "SYSTEM:ERROR?"):
            if not self.errors:
                return '+0,"No error"'
            code, text = self.errors.popleft()
            return f'{code},"{text}"'
        m = re.fullmatch(r"(OUTP|OUTPUT)\s+(ON|OFF|1|0)", upper)
        if m:
            self.output_on = m.group(2) in ("ON", "1")
            return None
        m = re.fullmatch(r"(VOLT|VOLTAGE|CURR|CURRENT)\s+" + _NUMBER, upper)
        if m:
            value = float(m.group(2))
            if m.group(1).startswith("VOLT"):
                if not 0.0 <= value <= self.cfg.max_voltage_v:
                    self.errors.append((-222, "Data out of range"))
                else:
                    self.voltage_set_v = value
            elif not 0.0 <= value <= self.cfg.max_current_a:
                self.errors.append((-222, "Data out of range"))
            else:
                self.current_limit_a = value
            return None
        self.errors.append((-113, "Undefined header"))
        return None

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
