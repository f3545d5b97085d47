"""Procedure and product files: YAML in, validated pydantic models out.

Every tunable of the calibration lives in YAML (config/procedures/*.yaml,
config/products/*.yaml). A mistake in a file is reported as `ConfigError` naming the file,
the line and the field, and saying what is allowed, so a process engineer can fix it without
reading Python. `load_yaml_model` is the one entry point (station.yaml uses it too).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from drivers.bounded import (
    MAX_ACCEL_DPS2,
    MAX_LIST,
    MAX_RATE_DPS,
    MAX_REPEATS,
    MAX_SUPPLY_V,
    ONE_DAY_S,
    ONE_HOUR_S,
    TEMP_HIGH_C,
    TEMP_LOW_C,
    Name,
    PathText,
    ShortName,
    Text,
)
from drivers.part_codes import CodeFormat
from drivers.yaml_input import ConfigError as ConfigError
from drivers.yaml_input import LoadedYaml as LoadedYaml
from drivers.yaml_input import format_validation_error as format_validation_error
from drivers.yaml_input import load_yaml_model as load_yaml_model
from drivers.yaml_input import read_yaml

# ---------------------------------------------------------------- YAML with line numbers
# The bounded reader lives with the lowest layer (drivers.yaml_input) so that the simulated
# bench's configuration is read by the same code; these names are re-exported from here.


def load_yaml(path: Path) -> LoadedYaml:
    """Read a YAML file within the input bounds (size, depth, aliases, UTF-8, no control
    characters), remembering the line of every field for error messages."""
    return read_yaml(path)


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


Seconds = Annotated[float, Field(le=ONE_DAY_S)]  # a duration or timeout: within a day
Rate = Annotated[float, Field(ge=-MAX_RATE_DPS, le=MAX_RATE_DPS)]
ChamberTemp = Annotated[float, Field(ge=TEMP_LOW_C, le=TEMP_HIGH_C)]
Volts = Annotated[float, Field(gt=0, le=MAX_SUPPLY_V)]
LimitValue = Annotated[float, Field(ge=-1e9, le=1e9)]


# ---------------------------------------------------------------- product file


class Limit(_Strict):
    """Acceptance limits of one measurement with an optional marginal band inside them.

    low <= marginal_low <= marginal_high <= high. A value inside [low, high] but outside
    [marginal_low, marginal_high] is MARGINAL: it passes but is flagged for review.
    """

    low: LimitValue | None = Field(
        None, description="lowest passing value (omit for no lower limit)"
    )
    high: LimitValue | None = Field(
        None, description="highest passing value (omit for no upper limit)"
    )
    marginal_low: LimitValue | None = Field(None, description="below this (and >= low): MARGINAL")
    marginal_high: LimitValue | None = Field(None, description="above this (and <= high): MARGINAL")
    units: ShortName = Field("", description="units of the value, for the certificate")

    @model_validator(mode="after")
    def _ordered(self) -> Limit:
        chain = [
            (n, v)
            for n, v in (
                ("low", self.low),
                ("marginal_low", self.marginal_low),
                ("marginal_high", self.marginal_high),
                ("high", self.high),
            )
            if v is not None
        ]
        for (n1, v1), (n2, v2) in zip(chain, chain[1:], strict=False):
            if v1 > v2:
                raise ValueError(
                    f"{n1} ({v1}) must not exceed {n2} ({v2}); "
                    "order low <= marginal_low <= marginal_high <= high"
                )
        if self.low is None and self.high is None:
            raise ValueError("give at least one of low or high")
        return self


LIMIT_NAMES = (
    "raw_bias_dps",
    "raw_scale_error",
    "noise_arw_deg_per_sqrt_h",
    "bias_instability_deg_per_h",
    "nonlinearity_pct_fs",
    "asymmetry",
    "bias_temp_coeff_dps_per_c",
    "scale_temp_coeff_per_c",
    "bias_supply_coeff_dps_per_v",
    "scale_supply_coeff_per_v",
    "residual_bias_dps",
    "residual_scale_error",
    "stop_table_consistency",
    "supply_current_a",
    "frames_lost_fraction",
)


class Limits(_Strict):
    """Limits per measurement name; a measurement without a limit is recorded, not judged."""

    raw_bias_dps: Limit | None = Field(
        None, description="uncalibrated bias at each condition, deg/s"
    )
    raw_scale_error: Limit | None = Field(
        None, description="uncalibrated scale - 1 at each condition"
    )
    noise_arw_deg_per_sqrt_h: Limit | None = Field(None, description="angle random walk")
    bias_instability_deg_per_h: Limit | None = Field(None, description="Allan floor / 0.664")
    nonlinearity_pct_fs: Limit | None = Field(
        None, description="largest residual from the line, % FS"
    )
    asymmetry: Limit | None = Field(None, description="(K+ - K-) / mean K")
    bias_temp_coeff_dps_per_c: Limit | None = Field(
        None, description="fitted bias temperature coefficient"
    )
    scale_temp_coeff_per_c: Limit | None = Field(
        None, description="fitted relative scale temperature coefficient"
    )
    bias_supply_coeff_dps_per_v: Limit | None = Field(
        None, description="fitted bias supply coefficient"
    )
    scale_supply_coeff_per_v: Limit | None = Field(
        None, description="fitted relative scale supply coefficient"
    )
    residual_bias_dps: Limit | None = Field(None, description="compensated output at rest, deg/s")
    residual_scale_error: Limit | None = Field(
        None, description="compensated scale error at the verification rates"
    )
    stop_table_consistency: Limit | None = Field(
        None, description="(stop scale - table scale) / combined k=2 uncertainty"
    )
    supply_current_a: Limit | None = Field(None, description="supply current per part, A")
    frames_lost_fraction: Limit | None = Field(None, description="lost frames / expected frames")


class Dispositions(_Strict):
    """What the operator does with a part of each verdict, shown with the verdict."""

    PASS: str = Field("", max_length=200, description="e.g. 'Place in tray A'")
    FAIL: str = Field("", max_length=200, description="e.g. 'Red bin: do not ship'")
    ERROR: str = Field("", max_length=200, description="e.g. 'Retest once, then call the engineer'")
    ABORTED: str = Field("", max_length=200, description="e.g. 'Retest the part'")


class ProductConfig(_Strict):
    """One product (part number): its range, nominal values, serial format and limits."""

    product: Name = Field(min_length=1, description="product name shown on the certificate")
    part_number: ShortName = Field("", description="part number")
    serial_pattern: str = Field(
        max_length=200,
        description="regular expression a scanned serial must match in full, e.g. '^SIM-[0-9]{4}$'"
    )
    range_dps: float = Field(
        gt=0, le=MAX_RATE_DPS, description="rated measurement range, +/- deg/s"
    )
    nominal_scale: float = Field(
        1.0, gt=0, le=1e6, description="nominal output per input (1 = datasheet)"
    )
    reference_temperature_c: ChamberTemp = Field(25.0, description="T0 of the calibration")
    reference_supply_v: Volts = Field(5.0, description="V0 of the calibration")
    current_limit_a: float = Field(
        0.05, gt=0, le=20, description="supply current limit per part, A"
    )
    supply_range_v: tuple[Volts, Volts] | None = Field(
        None,
        description="supply levels [low, high] V the part may be run at (its datasheet's "
        "operating range); default: reference_supply_v +/- 10 %",
    )
    bias_instability_deg_per_h: float = Field(
        15.0,
        ge=0,
        le=1e6,
        description="typical bias instability of the product: the bias wanders by "
        "about this much between conditions (a floor for the bias uncertainty when the record "
        "is too short to resolve it)",
    )
    codes: CodeFormat = Field(
        default_factory=CodeFormat,
        description="how the part's raw rate and temperature codes read in deg/s and C "
        "(default: the ADIS16130's 24-bit offset-binary codes)",
    )
    limits: Limits = Field(default_factory=Limits, description="acceptance limits")
    handling_temp_range_c: tuple[float, float] = Field(
        (10.0, 40.0),
        description="chamber temperatures [low, high] C at which the part and fixture may be "
        "handled; a procedure's chamber.safe_temp_c must lie within",
    )
    decision_rule: Literal["simple", "guard_banded"] = Field(
        "simple",
        description="how a measurement is judged against its limits (stated on the "
        "certificate): simple acceptance (inside the limits passes), or guard_banded (the "
        "acceptance zone is the limits narrowed by the measurement's expanded uncertainty)",
    )
    dispositions: Dispositions | None = Field(
        None,
        description="what the operator does with a part of each verdict (PASS, FAIL, ERROR, "
        "ABORTED), shown with the verdict on the operator screen",
    )

    @property
    def supply_limits_v(self) -> tuple[float, float]:
        """The supply levels the part may be run at, V."""
        if self.supply_range_v is not None:
            return self.supply_range_v
        return 0.9 * self.reference_supply_v, 1.1 * self.reference_supply_v

    @field_validator("serial_pattern")
    @classmethod
    def _regex(cls, value: str) -> str:
        try:
            re.compile(value)
        except re.error as exc:
            raise ValueError(f"not a valid regular expression ({exc})") from exc
        return value

    @model_validator(mode="after")
    def _codes_cover_range(self) -> ProductConfig:
        low_dps, high_dps = self.codes.rate_span_dps()
        if low_dps > -self.range_dps or high_dps < self.range_dps:
            raise ValueError(
                f"codes: the rate code reaches only {low_dps:g} .. {high_dps:g} deg/s, less "
                f"than the rated range +/-{self.range_dps:g} deg/s; check rate_zero_code, "
                "rate_counts_per_dps and rate_width_bits against the datasheet"
            )
        return self


# ---------------------------------------------------------------- procedure file


class StepPolicy(_Strict):
    timeout_s: Seconds = Field(
        3600.0, gt=0, description="station seconds before the step times out"
    )
    retries: int = Field(0, ge=0, le=5, description="extra attempts after an instrument timeout")


class PowerConfig(_Strict):
    settle_s: float = Field(
        2.0, ge=0, le=ONE_HOUR_S, description="wait after switching the supply on"
    )
    supply_tolerance_v: float = Field(
        0.05, gt=0, le=10, description="allowed |measured - set| supply"
    )
    output_rate_hz: Literal[50, 100, 200, 500, 1000] = Field(
        100, description="part output data rate, Hz"
    )


class ConditionsConfig(_Strict):
    temperatures_c: list[ChamberTemp] = Field(
        min_length=1, max_length=MAX_LIST, description="chamber setpoints, C"
    )
    supplies_v: list[Volts] = Field(
        min_length=1, max_length=MAX_LIST, description="supply levels, V"
    )
    order: Literal["min_transitions", "as_listed"] = Field(
        "min_transitions",
        description="min_transitions: both supplies at one temperature, start at the "
        "temperature the chamber is nearest to; as_listed: temperatures in file order",
    )

    @field_validator("supplies_v")
    @classmethod
    def _positive(cls, value: list[float]) -> list[float]:
        if any(v <= 0 for v in value):
            raise ValueError("supply levels must be positive volts")
        return value


class ChamberConfig(_Strict):
    ramp_c_per_min: float = Field(5.0, ge=0, le=100, description="chamber ramp rate (0 = fastest)")
    safe_temp_c: float = Field(
        25.0, ge=0, le=50, description="setpoint the chamber goes to on any exit (0..50 C: "
        "a part must be safe to handle)"
    )
    setpoint_band_c: float = Field(0.5, gt=0, le=50, description="air within this of setpoint")
    setpoint_timeout_s: Seconds = Field(3600.0, gt=0, description="time allowed to reach setpoint")


class StabilityConfig(_Strict):
    """Thermal stability, judged on each part's own temperature sensor."""

    window_s: Seconds = Field(60.0, gt=0, description="window over which slope and band are judged")
    slope_c_per_min: float = Field(
        0.05, gt=0, le=100, description="largest |die temperature slope|"
    )
    band_c: float = Field(
        0.1, gt=0, le=100, description="largest peak-to-peak die temperature in the window"
    )
    target_tolerance_c: float | None = Field(
        None, gt=0, le=100, description="optional: die temperature within this of the setpoint"
    )
    timeout_s: Seconds = Field(3600.0, gt=0, description="time allowed to reach stability")
    check_interval_s: float = Field(
        5.0, gt=0, le=ONE_HOUR_S, description="how often stability is evaluated"
    )


class BiasConfig(_Strict):
    dwell_s: Seconds | Literal["auto"] = Field(
        30.0, description="static averaging time, s, or 'auto' (from Allan deviation and target)"
    )
    target_accuracy_dps: float = Field(0.005, gt=0, le=100, description="k=2 target for 'auto'")
    min_dwell_s: Seconds = Field(10.0, gt=0, description="pilot dwell for 'auto'")
    max_dwell_s: Seconds = Field(300.0, gt=0, description="cap for 'auto'")
    wander_factor: float = Field(
        1.5,
        ge=0,
        le=100,
        description="bias wander between conditions, in units of the bias "
        "instability, added to each condition's bias uncertainty (0: white noise only)",
    )

    @field_validator("dwell_s")
    @classmethod
    def _positive(cls, value: float | str) -> float | str:
        if not isinstance(value, str) and value <= 0:
            raise ValueError("dwell must be a positive number of seconds or 'auto'")
        return value


class RateTableConfig(_Strict):
    enabled: bool = True
    rates_dps: list[Rate] = Field(
        min_length=2, max_length=MAX_LIST, description="rate set, deg/s (both signs)"
    )
    plateau_dwell_s: Seconds = Field(10.0, gt=0, description="averaging time on each plateau")
    settle_s: float = Field(
        1.0, ge=0, le=ONE_HOUR_S, description="wait after at-rate before averaging"
    )
    accel_dps2: float = Field(
        200.0, gt=0, le=MAX_ACCEL_DPS2, description="table acceleration, deg/s^2"
    )
    repeats: int = Field(1, ge=1, le=MAX_REPEATS, description="passes through the rate set")
    at_rate_timeout_s: Seconds = Field(60.0, gt=0, description="time allowed to reach a rate")


class StopMethodConfig(_Strict):
    enabled: bool = True
    stop_angle_deg: float = Field(90.0, gt=0, le=360, description="angle between the stops")
    move_time_s: float = Field(3.5, gt=0, le=ONE_HOUR_S, description="duration of each smooth move")
    static_s: float = Field(
        5.0, gt=0, le=ONE_HOUR_S, description="rest before, between and after the moves"
    )
    bias_window_s: float = Field(
        3.0, gt=0, le=ONE_HOUR_S, description="leading rest used for the bias"
    )
    repeats: int = Field(1, ge=1, le=MAX_REPEATS, description="out-and-back pairs")
    reference: Literal["encoder", "fixture"] = Field(
        "encoder", description="angle reference: the table encoder or the fixture's stop angle"
    )
    move_timeout_s: Seconds = Field(60.0, gt=0, description="time allowed for a move")


class PositionsConfig(_Strict):
    """Multi-position static: the table at rest at several angles, one static window each.

    Rotation about a vertical axis changes nothing for a perfect part at rest; a part whose
    sensitive axis is tilted in the fixture sees a share of gravity that turns with the table
    (g sensitivity), which only static windows at several angles can show. Disabled unless
    the section is present."""

    enabled: bool = True
    angles_deg: list[float] = Field(
        default_factory=lambda: [0.0, 90.0, 180.0, 270.0],
        min_length=1,
        max_length=MAX_LIST,
        description="table angles (encoder, deg) at which the part rests, in this order",
    )
    dwell_s: Seconds = Field(10.0, gt=0, description="static window at each angle, s")
    settle_s: float = Field(
        1.0, ge=0, le=ONE_HOUR_S, description="wait after in-position before the window"
    )
    accel_dps2: float = Field(
        100.0, gt=0, le=MAX_ACCEL_DPS2, description="acceleration of each move, deg/s^2"
    )
    at: Literal["every_condition", "first_condition"] = Field(
        "every_condition",
        description="every_condition: after the bias step at each condition; "
        "first_condition: only at the first",
    )
    move_timeout_s: Seconds = Field(60.0, gt=0, description="time allowed for a move")

    @field_validator("angles_deg")
    @classmethod
    def _angles(cls, value: list[float]) -> list[float]:
        if any(not -3600.0 <= a <= 3600.0 for a in value):
            raise ValueError("angles must lie within +/-3600 deg")
        return value


class FitConfig(_Strict):
    source: Literal["rate_table", "stop_method", "both"] = Field(
        "rate_table",
        description="which scale estimate feeds the fit (both: weighted by uncertainty)",
    )


class VerifyConfig(_Strict):
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


class StreamConfig(_Strict):
    max_lost_fraction: float = Field(0.001, ge=0, le=1, description="allowed lost/expected frames")
    silent_timeout_s: float = Field(
        5.0, gt=0, le=ONE_HOUR_S, description="no frames this long: part is silent"
    )
    max_lost_frames_per_window: int = Field(
        2, ge=0, le=100_000, description="lost frames allowed in any one analysis window"
    )


class StepsConfig(_Strict):
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


class ProcedureConfig(_Strict):
    """A calibration procedure: what to measure, where, and how long."""

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
    def _scale_source(self) -> ProcedureConfig:
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


def load_product(path: Path) -> tuple[ProductConfig, LoadedYaml]:
    return load_yaml_model(path, ProductConfig)


def load_procedure(path: Path) -> tuple[ProcedureConfig, LoadedYaml]:
    return load_yaml_model(path, ProcedureConfig)


def check_procedure_for_product(
    procedure: ProcedureConfig,
    procedure_file: LoadedYaml,
    product: ProductConfig,
    product_file: LoadedYaml,
) -> None:
    """Cross-checks of a procedure against the product it calibrates: every rate of the rate
    set and of the verification within the part's rated range, every supply level within the
    part's supply range. ConfigError with one line per problem, naming the procedure's file
    and line and the product's limit."""
    problems = [*_rate_problems(procedure, procedure_file, product, product_file),
                *_supply_problems(procedure, procedure_file, product, product_file)]
    if problems:
        raise ConfigError("\n".join(problems))


def _where(loaded: LoadedYaml, *path: str | int) -> str:
    for n in range(len(path), 0, -1):
        line = loaded.lines.get(path[:n])
        if line is not None:
            return f"{loaded.path}:{line}"
    return str(loaded.path)


def _rate_problems(
    procedure: ProcedureConfig, procedure_file: LoadedYaml, product: ProductConfig,
    product_file: LoadedYaml,
) -> list[str]:
    out = []
    for section, rates in (
        ("rate_table", procedure.rate_table.rates_dps if procedure.rate_table else []),
        ("verify", procedure.verify.rates_dps if procedure.verify else []),
    ):
        for i, rate in enumerate(rates):
            if abs(rate) > product.range_dps:
                out.append(
                    f"{_where(procedure_file, section, 'rates_dps', i)}: field "
                    f"{section}.rates_dps.{i}: {rate:g} deg/s is beyond the range of "
                    f"{product.product} (+/-{product.range_dps:g} deg/s, {product_file.path}); "
                    "give rates within the part's range"
                )
    return out


def _supply_problems(
    procedure: ProcedureConfig, procedure_file: LoadedYaml, product: ProductConfig,
    product_file: LoadedYaml,
) -> list[str]:
    low, high = product.supply_limits_v
    levels: list[tuple[tuple[str | int, ...], float]] = [
        (("conditions", "supplies_v", i), v) for i, v in enumerate(procedure.conditions.supplies_v)
    ]
    if procedure.verify is not None and procedure.verify.supply_v is not None:
        levels.append((("verify", "supply_v"), procedure.verify.supply_v))
    return [
        f"{_where(procedure_file, *path)}: field {'.'.join(map(str, path))}: {v:g} V is "
        f"outside the supply range [{low:g}, {high:g}] V of {product.product} "
        f"({product_file.path}, supply_range_v): the part could be damaged; give supply "
        "levels within the part's range"
        for path, v in levels
        if not low <= v <= high
    ]
