"""The old section form of a procedure file, read only to convert it to the step list.

Before procedures were lists of steps, a procedure file had one section per measurement
(`power:`, `stability:`, `bias:`, `rate_table:`, `stop_method:`, `positions:`, `fit:`,
`verify:`) and `steps:` held timeouts by step; the engine decided the order. `convert`
turns such a file into the list form the station runs (`station procedure convert`), with
the same steps in the same order and the same settings.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

from pydantic import Field, model_validator

from common.bounded import (
    MAX_LIST,
    ONE_HOUR_S,
    Name,
    PathText,
    ShortName,
    Text,
)
from common.yaml_input import LoadedYaml, load_yaml_model
from procedures.loading.config import ChamberConfig, ConditionsConfig, StreamConfig
from procedures.steps.bias import BiasSettings
from procedures.steps.fit import FitSettings
from procedures.steps.positions import PositionsSettings
from procedures.steps.power import PowerSettings
from procedures.steps.stop import StopSettings
from procedures.steps.sweep import RateTableSettings
from procedures.steps.thermal import ThermalSettings
from procedures.units import Rate, Seconds, StrictModel, Volts


class StepPolicy(StrictModel):
    timeout_s: Seconds = Field(
        3600.0, gt=0, description="station seconds before the step times out"
    )
    retries: int = Field(0, ge=0, le=5, description="extra attempts after an instrument timeout")


# The old sections hold the same settings as the step types they became: each section is the
# step's own Settings (plus `enabled` where the old form had it), so the two cannot drift.


class PowerConfig(PowerSettings):
    output_rate_hz: Literal[50, 100, 200, 500, 1000] = Field(
        100, description="part output data rate, Hz"
    )


class StabilityConfig(ThermalSettings):
    """Thermal stability; the old form called the step's `stability_timeout_s` `timeout_s`."""

    @model_validator(mode="before")
    @classmethod
    def _old_timeout_name(cls, data: Any) -> Any:
        if isinstance(data, dict) and "timeout_s" in data:
            if "stability_timeout_s" in data:
                raise ValueError("give stability timeout_s or stability_timeout_s, not both")
            data = {("stability_timeout_s" if k == "timeout_s" else k): v
                    for k, v in data.items()}
        return data


BiasConfig = BiasSettings
FitConfig = FitSettings


class RateTableConfig(RateTableSettings):
    enabled: bool = True


class StopMethodConfig(StopSettings):
    enabled: bool = True


class PositionsConfig(PositionsSettings):
    """Multi-position static; disabled unless the section is present."""

    enabled: bool = True


class VerifyConfig(StrictModel):
    enabled: bool = True
    method: Literal["auto", "rate_table", "stop_method"] = Field(
        "auto", description="auto: rate table if enabled, else stop moves with compensation on"
    )
    rates_dps: list[Rate] = Field(
        default_factory=list,
        max_length=MAX_LIST,
        description="verification rates, deg/s (rate_table method)",
    )
    dwell_s: Seconds = Field(10.0, gt=0, description="averaging time at each rate")
    settle_s: float = Field(1.0, ge=0, le=ONE_HOUR_S)
    supply_v: Volts | None = Field(None, description="supply during verification (default V0)")


class StepsConfig(StrictModel):
    default: StepPolicy = StepPolicy()
    power: StepPolicy | None = None
    thermal: StepPolicy | None = None
    bias: StepPolicy | None = None
    rate_table: StepPolicy | None = None
    stop_method: StepPolicy | None = None
    positions: StepPolicy | None = None
    fit: StepPolicy | None = None
    program: StepPolicy | None = None
    verify: StepPolicy | None = None

    def policy(self, step: str) -> StepPolicy:
        return getattr(self, step, None) or self.default


class SectionProcedure(StrictModel):
    """A procedure in the old section form (read only to convert it)."""

    name: Name = Field(min_length=1, description="procedure name shown on the certificate")
    version: ShortName = Field("1", description="procedure version")
    description: Text = ""
    product: PathText | None = Field(
        None, description="product file, relative to this file (overridden by --product)"
    )
    power: PowerConfig = PowerConfig()
    conditions: ConditionsConfig
    chamber: ChamberConfig = ChamberConfig()
    stability: StabilityConfig = StabilityConfig()
    bias: BiasConfig = BiasConfig()
    rate_table: RateTableConfig | None = None
    stop_method: StopMethodConfig | None = None
    positions: PositionsConfig | None = Field(
        None, description="optional multi-position static step (absent: not run)"
    )
    fit: FitConfig = FitConfig()
    verify: VerifyConfig | None = None
    stream: StreamConfig = StreamConfig()
    steps: StepsConfig = StepsConfig()

    @model_validator(mode="after")
    def _scale_source(self) -> SectionProcedure:
        table = self.rate_table is not None and self.rate_table.enabled
        stop = self.stop_method is not None and self.stop_method.enabled
        if not (table or stop):
            raise ValueError("enable at least one of rate_table or stop_method")
        method = self.verify_method
        if method == "rate_table" and not (table and self.verify and self.verify.rates_dps):
            raise ValueError(
                "verify.method rate_table needs rate_table enabled and verify.rates_dps"
            )
        if method == "stop_method" and not stop:
            raise ValueError("verify.method stop_method needs stop_method enabled")
        need = {"rate_table": table, "stop_method": stop, "both": table and stop}
        if not need[self.fit.source]:
            raise ValueError(
                f"fit.source is {self.fit.source!r} but that method is not enabled; "
                "enable it or choose a source that is"
            )
        return self

    @property
    def verify_method(self) -> str | None:
        """Which verification runs after programming (None: none)."""
        v = self.verify
        if v is None or not v.enabled:
            return None
        if v.method == "auto":
            return "rate_table" if self.table_enabled and v.rates_dps else "stop_method"
        return v.method

    @property
    def table_enabled(self) -> bool:
        return self.rate_table is not None and self.rate_table.enabled

    @property
    def stop_enabled(self) -> bool:
        return self.stop_method is not None and self.stop_method.enabled

    @property
    def positions_enabled(self) -> bool:
        return self.positions is not None and self.positions.enabled


def load_section_procedure(path: Path) -> tuple[SectionProcedure, LoadedYaml]:
    return load_yaml_model(path, SectionProcedure)


_POLICY_DEFAULT = StepPolicy()


class _Converter:
    """One old file to the list form; `raw` (the file as read) keeps numbers as written."""

    def __init__(self, old: SectionProcedure, raw: dict[str, Any]) -> None:
        self.old, self.raw = old, raw
        self.policies = old.steps
        self.explicit = set(old.steps.model_fields_set)

    def given(self, section: str, drop: tuple[str, ...] = ()) -> dict[str, Any]:
        """The fields of `section` the file gave, as written (defaults stay defaults)."""
        model = getattr(self.old, section)
        raw = self.raw.get(section)
        dumped = model.model_dump(exclude_unset=True, mode="json")
        return {k: (raw[k] if isinstance(raw, dict) and k in raw else v)
                for k, v in dumped.items() if k not in drop}

    def entry(self, step: str, settings: dict[str, Any], policy: str) -> dict[str, Any]:
        out: dict[str, Any] = {"step": step, **settings}
        pol = getattr(self.policies, policy, None)
        if pol is None and "default" in self.explicit:
            pol = self.policies.default
        if pol is not None:
            if pol.timeout_s != _POLICY_DEFAULT.timeout_s:
                out["timeout_s"] = _number(pol.timeout_s)
            if pol.retries != _POLICY_DEFAULT.retries:
                out["retries"] = pol.retries
        return out

    def steps(self) -> list[dict[str, Any]]:
        old = self.old
        stability = self.given("stability")
        loop = [self.entry("thermal", stability, "thermal"),
                self.entry("bias", self.given("bias"), "bias")]
        for section, enabled in (("positions", old.positions_enabled),
                                 ("rate_table", old.table_enabled),
                                 ("stop_method", old.stop_enabled)):
            if enabled:
                loop.append(self.entry(section, self.given(section, ("enabled",)), section))
        out = [
            self.entry("power_identify", self.given("power", ("output_rate_hz",)), "power"),
            {"for_each": "condition", "steps": loop},
            self.entry("fit", self.given("fit"), "fit"),
            self.entry("program", {}, "program"),
        ]
        method, verify = old.verify_method, old.verify
        if method == "rate_table" and verify is not None:
            settings = self.given("verify", ("enabled", "method"))
            table = old.rate_table
            settings["accel_dps2"] = (
                self.given("rate_table").get("accel_dps2", table.accel_dps2) if table else 100
            )
            out.append(self.entry("verify", settings, "verify"))
        elif method == "stop_method":
            settings = self.given("stop_method", ("enabled",))
            if verify is not None and verify.supply_v is not None:
                settings["supply_v"] = self.given("verify")["supply_v"]
            out.append(self.entry("verify_stop", settings, "verify"))
        return out


def _number(value: float) -> float | int:
    return int(value) if float(value).is_integer() else value


def convert(old: SectionProcedure, raw: dict[str, Any] | None = None) -> dict[str, Any]:
    """The list form of an old section-form procedure (same steps, order and settings);
    `raw`: the file as read, so that numbers keep the form they were written in."""
    conv = _Converter(old, raw or {})
    out: dict[str, Any] = {"name": old.name, "version": old.version}
    if old.description:
        out["description"] = old.description
    if old.product:
        out["product"] = old.product
    if "output_rate_hz" in old.power.model_fields_set:
        out["output_rate_hz"] = old.power.output_rate_hz
    out["conditions"] = conv.given("conditions")
    for key in ("chamber", "stream"):
        given = conv.given(key)
        if given:
            out[key] = given
    out["steps"] = conv.steps()
    return out
