"""Keysight E36300 series triple-output supplies (E36311A, E36312A, E36313A): the
`supply.keysight-e36300` family.

Each model's outputs have their own ranges (`MODELS`, from Keysight's E36300 Series data
sheet and programming guide); the pre-flight checks a procedure against the range of the
output the parts hang on, found from *IDN?'s model. Every command names its output with a
SCPI channel list, so nothing depends on the selected output (`INST:SEL`):
`VOLT 5.000,(@1)`, `CURR 0.1000,(@1)`, `OUTP 1,(@1)`, `OUTP? (@1)`,
`MEAS:VOLT? (@1)`, `MEAS:CURR? (@1)`, `VOLT? (@1)`, `CURR? (@1)`, `SYST:ERR?`. The E36300 has
LAN (raw SCPI socket on port 5025, VXI-11, HiSLIP), USBTMC and GPIB, no serial port.
"""

from __future__ import annotations

from typing import Any

from pydantic import Field

from drivers.supply import ModelOutputs, ScpiDialect, ScpiSupply, SupplySettings, open_checked

NAME = "Keysight E36300 supply"
CHANNELS = 3
# each output's (lowest V, highest V, highest A); the E36311A's output 3 is negative
MODELS: ModelOutputs = {
    "E36311A": {1: (0.0, 6.0, 5.0), 2: (0.0, 25.0, 1.0), 3: (-25.0, 0.0, 1.0)},
    "E36312A": {1: (0.0, 6.0, 5.0), 2: (0.0, 25.0, 1.0), 3: (0.0, 25.0, 1.0)},
    "E36313A": {1: (0.0, 6.0, 10.0), 2: (0.0, 25.0, 2.0), 3: (0.0, 25.0, 2.0)},
}


class KeysightE36300Dialect(ScpiDialect):
    """SCPI with an explicit channel list on every output command."""

    def __init__(self, channel: int = 1) -> None:
        if not 1 <= channel <= CHANNELS:
            raise ValueError(f"the E36300 has outputs 1..{CHANNELS}, not {channel}")
        self.channel = channel
        self._at = f"(@{channel})"

    def output_name(self, model: str) -> str:
        return f"output {self.channel} of the Keysight {model}"

    def model_output(self, model: str) -> tuple[float, float, float] | None:
        outputs = MODELS.get(model.strip().upper())
        return None if outputs is None else outputs.get(self.channel)

    def range_queries(self) -> tuple[str, str]:
        return f"VOLT? MAX,{self._at}", f"CURR? MAX,{self._at}"

    def set_voltage(self, supply_v: float) -> str:
        return f"VOLT {supply_v:.3f},{self._at}"

    def set_current_limit(self, current_a: float) -> str:
        return f"CURR {current_a:.4f},{self._at}"

    def output(self, on: bool) -> str:
        return f"OUTP {1 if on else 0},{self._at}"

    def output_query(self) -> str:
        return f"OUTP? {self._at}"

    def measure_voltage(self) -> str:
        return f"MEAS:VOLT? {self._at}"

    def measure_current(self) -> str:
        return f"MEAS:CURR? {self._at}"

    def voltage_setting_query(self) -> str:
        return f"VOLT? {self._at}"

    def current_limit_query(self) -> str:
        return f"CURR? {self._at}"


class Settings(SupplySettings):
    """The `supply.keysight-e36300` entry of station.yaml."""

    channel: int = Field(1, ge=1, le=CHANNELS, description="the output the parts hang on")


def factory(settings: dict[str, Any]) -> ScpiSupply:
    """Entry point `supply.keysight-e36300`: validate (ValidationError propagates), connect."""
    s = Settings.model_validate(settings)
    return open_checked(s, KeysightE36300Dialect(s.channel), baud=9600, name=NAME)
