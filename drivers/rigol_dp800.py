"""Rigol DP800 series supplies (DP811, DP821, DP831, DP832): the `supply.rigol-dp800` family.

Outputs and measurements name their channel (`:OUTP CH1,ON`, `:OUTP? CH1` -> ON/OFF,
`:MEAS:VOLT? CH1`, `:MEAS:CURR? CH1`); the levels are set on the channel selected in the same
message (`:INST:NSEL 1;:VOLT 5.000`, `:INST:NSEL 1;:CURR 0.1000`), so a selection changed on the
front panel between two commands cannot redirect them; the set levels are read back with
`:APPL? CH1,VOLT` and `:APPL? CH1,CURR`; errors with `:SYST:ERR?`. Each model's channels have
their own ratings (`MODELS`, from Rigol's DP800 data sheet and programming guide), which the
pre-flight checks a procedure against (the model from *IDN?; `DP832A` is a `DP832`). The
DP800 has LAN (raw SCPI socket on port 5555 on most firmware, VXI-11), USBTMC and RS-232
(9600 baud by default).
"""

from __future__ import annotations

from typing import Any

from pydantic import Field

from drivers.supply import ModelOutputs, ScpiDialect, ScpiSupply, SupplySettings, open_checked

NAME = "Rigol DP800 supply"
CHANNELS = 3
# each channel's rating, (lowest V, highest V, highest A); the DP831's CH3 is negative. The
# DP811 (20 V / 10 A or 40 V / 5 A, by its range setting) is asked (`:SOUR1:VOLT? MAX`).
MODELS: ModelOutputs = {
    "DP832": {1: (0.0, 30.0, 3.0), 2: (0.0, 30.0, 3.0), 3: (0.0, 5.0, 3.0)},
    "DP831": {1: (0.0, 8.0, 5.0), 2: (0.0, 30.0, 2.0), 3: (-30.0, 0.0, 2.0)},
    "DP821": {1: (0.0, 60.0, 1.0), 2: (0.0, 8.0, 10.0)},
}


class RigolDp800Dialect(ScpiDialect):
    """The DP800's channel-named commands."""

    error_query = ":SYST:ERR?"

    def __init__(self, channel: int = 1) -> None:
        if not 1 <= channel <= CHANNELS:
            raise ValueError(f"the DP800 has outputs CH1..CH{CHANNELS}, not {channel}")
        self.channel = channel
        self._ch = f"CH{channel}"

    def output_name(self, model: str) -> str:
        return f"{self._ch} of the Rigol {model}"

    def model_output(self, model: str) -> tuple[float, float, float] | None:
        outputs = MODELS.get(model.strip().upper().removesuffix("A"))
        return None if outputs is None else outputs.get(self.channel)

    def range_queries(self) -> tuple[str, str]:
        return f":SOUR{self.channel}:VOLT? MAX", f":SOUR{self.channel}:CURR? MAX"

    def set_voltage(self, supply_v: float) -> str:
        return f":INST:NSEL {self.channel};:VOLT {supply_v:.3f}"

    def set_current_limit(self, current_a: float) -> str:
        return f":INST:NSEL {self.channel};:CURR {current_a:.4f}"

    def output(self, on: bool) -> str:
        return f":OUTP {self._ch},{'ON' if on else 'OFF'}"

    def output_query(self) -> str:
        return f":OUTP? {self._ch}"

    def measure_voltage(self) -> str:
        return f":MEAS:VOLT? {self._ch}"

    def measure_current(self) -> str:
        return f":MEAS:CURR? {self._ch}"

    def voltage_setting_query(self) -> str:
        return f":APPL? {self._ch},VOLT"

    def current_limit_query(self) -> str:
        return f":APPL? {self._ch},CURR"


class Settings(SupplySettings):
    """The `supply.rigol-dp800` entry of station.yaml."""

    channel: int = Field(1, ge=1, le=CHANNELS, description="the output the parts hang on")
    baud: int = Field(9600, ge=300, le=115200, description="RS-232 baud rate (ASRL only)")


def factory(settings: dict[str, Any]) -> ScpiSupply:
    """Entry point `supply.rigol-dp800`: validate (ValidationError propagates), connect."""
    s = Settings.model_validate(settings)
    return open_checked(s, RigolDp800Dialect(s.channel), baud=s.baud, name=NAME)
