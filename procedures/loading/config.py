"""Procedure and product files: YAML in, validated pydantic models out.

Every tunable of the calibration lives in YAML (config/procedures/*.yaml,
config/products/*.yaml). A mistake in a file is reported as `ConfigError` naming the file,
the line and the field, and saying what is allowed, so a process engineer can fix it without
reading Python. `load_yaml_model` is the one entry point (station.yaml uses it too).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any, Literal

from pydantic import (
    Field,
    PrivateAttr,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)

from common.bounded import (
    MAX_LIST,
    MAX_RATE_DPS,
    ONE_HOUR_S,
    Name,
    PathText,
    ShortName,
    Text,
)
from common.yaml_input import (
    ConfigError,
    LoadedYaml,
    format_validation_error,
    load_yaml_model,
    read_yaml,
)
from drivers.part_codes import CodeFormat
from procedures.analysis.consistency import per_condition_limit
from procedures.loading.step_list import (
    Node,
    StepEntry,
    entries,
    expand,
    measurement_problems,
    parse_steps,
)
from procedures.runtime.conditions import Condition, plan_conditions, with_revisit
from procedures.runtime.limits import LIMIT_NAMES, Limit, Limits
from procedures.steps.registry import StepType
from procedures.units import ChamberTemp, Seconds, StrictModel, Volts

# ---------------------------------------------------------------- YAML with line numbers
# The bounded reader lives with the lowest layer (common.yaml_input) so that the simulated
# bench's configuration and station.yaml are read by the same code; import it from there.


def load_yaml(path: Path) -> LoadedYaml:
    """Read a YAML file within the input bounds (size, depth, aliases, UTF-8, no control
    characters), remembering the line of every field for error messages."""
    return read_yaml(path)


# ---------------------------------------------------------------- product file


FitOrder = Literal[1, 2, 3]
FIRST_ORDER: FitOrder = 1


class CalibrationStorage(StrictModel):
    """What the part's calibration registers can hold."""

    fit_orders: list[FitOrder] = Field(
        default_factory=lambda: [FIRST_ORDER],
        min_length=1,
        max_length=3,
        description="temperature-fit orders the part's registers hold (1: the eight "
        "first-order registers; 2, 3: also bias_tc2/scale_tc2, bias_tc3/scale_tc3)",
    )


class ConsistencyRule(StrictModel):
    """How often the stop-vs-table judgement (`stop_table_consistency`, E_n at each condition)
    may reject a good part. The |E_n| limit at each condition is derived from these and the
    number of conditions the procedure judges (procedures.analysis.consistency, Sidak), so
    the rate holds for the part over all its conditions, whatever the procedure."""

    false_reject_rate: float = Field(
        ge=1e-6, le=0.2, description="share of good parts the judgement may reject, over all "
        "the conditions a part is judged at (0.001: one in a thousand)"
    )
    marginal_rate: float | None = Field(
        None, ge=1e-6, le=0.5, description="share of good parts flagged MARGINAL over all "
        "their conditions (omit: no marginal band)"
    )

    @model_validator(mode="after")
    def _marginal_above_reject(self) -> ConsistencyRule:
        if self.marginal_rate is not None and self.marginal_rate <= self.false_reject_rate:
            raise ValueError(
                f"marginal_rate ({self.marginal_rate:g}) must exceed false_reject_rate "
                f"({self.false_reject_rate:g}): the marginal band lies inside the limits"
            )
        return self

    def limit(self, judgements: int) -> Limit:
        """The per-condition |E_n| limit for a part judged at `judgements` conditions."""
        k = per_condition_limit(self.false_reject_rate, judgements)
        marginal = None
        if self.marginal_rate is not None:
            marginal = per_condition_limit(self.marginal_rate, judgements)
        return Limit(
            low=-k, high=k, units="1",
            marginal_low=None if marginal is None else -marginal,
            marginal_high=marginal,
        )


class Dispositions(StrictModel):
    """What the operator does with a part of each verdict, shown with the verdict."""

    PASS: str = Field("", max_length=200, description="e.g. 'Place in tray A'")
    FAIL: str = Field("", max_length=200, description="e.g. 'Red bin: do not ship'")
    ERROR: str = Field("", max_length=200, description="e.g. 'Retest once, then call the engineer'")
    ABORTED: str = Field("", max_length=200, description="e.g. 'Retest the part'")


class ThermalTypical(StrictModel):
    """The product's typical thermal behaviour between its temperature sensor and its
    sensing element (issue 28; docs/simulated-bench.md): typical values and 1-sigma spreads.
    Declared for the procedures that will judge a part's lag and hysteresis against them;
    the simulated bench's defaults (config/sim part_physics.thermal) are these values."""

    element_tau_s: float = Field(
        ge=0, le=3600, description="the sensing element's lag behind the on-chip sensor, s"
    )
    element_tau_sigma_s: float = Field(ge=0, le=3600)
    gradient_sigma_dps_per_c_per_min: float = Field(
        ge=0, le=10, description="bias per rate of die temperature change, (deg/s)/(C/min), 1 sigma"
    )
    hysteresis_dps: float = Field(
        ge=0, le=10, description="bias difference between heating and cooling, deg/s"
    )
    hysteresis_sigma_dps: float = Field(ge=0, le=10)
    hysteresis_width_c: float = Field(
        gt=0, le=50, description="half-width of the temperature reversal that switches it, C"
    )


class ProductConfig(StrictModel):
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
    rate_random_walk_deg_per_h_per_sqrt_h: float = Field(
        0.0,
        ge=0,
        le=1e6,
        description="typical rate random walk of the product (the Allan deviation's +1/2 "
        "slope): the bias drifts by about this much per square root of hour, which a "
        "three-axis fit counts between windows far apart (0: not counted)",
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
    calibration: CalibrationStorage = Field(
        default_factory=CalibrationStorage,
        description="what the part's calibration registers hold (fit_orders)",
    )
    die_tau_s: float = Field(
        300.0, gt=0, le=1e4, description="the die's thermal lag behind the chamber air, s: "
        "the starting value the fastest thermal strategy learns from each part's own sensor"
    )
    max_part_temperature_c: ChamberTemp | None = Field(
        None, description="highest temperature the part may see, C: the pre-flight refuses a "
        "condition whose die, self-heating included, is predicted above it, and the fastest "
        "thermal strategy's overshoot stays below it; default: the chamber's limits only"
    )
    min_part_temperature_c: ChamberTemp | None = Field(
        None, description="lowest temperature the part may see, C (the pre-flight refuses a "
        "colder condition; the fastest strategy's undershoot stays above it); default: the "
        "chamber's limits only"
    )
    self_heating_c_per_w: float | None = Field(
        None, ge=0, le=1e4, description="die temperature rise per watt the part draws, C/W "
        "(the fastest strategy predicts the step at a supply change); default: scaled from "
        "the rise seen at the previous supply"
    )
    self_heating_tau_s: float = Field(
        90.0, gt=0, le=1e4, description="time constant of the self-heating, s"
    )
    thermal_typical: ThermalTypical | None = Field(
        None, description="typical lag, gradient bias and hysteresis between the part's "
        "temperature sensor and its sensing element, and their spreads (docs/simulated-bench.md)"
    )
    axes: Literal[1, 3] = Field(
        1,
        description="rate axes of the part: 1 (a single-axis gyro) or 3 (x, y, z in one "
        "package, calibrated in cube orientations: docs/three-axis.md)",
    )
    consistency: ConsistencyRule | None = Field(
        None,
        description="the stop-vs-table judgement's false-reject rate per part "
        "(false_reject_rate, marginal_rate); its per-condition limit is derived for each "
        "procedure. Give this or limits.stop_table_consistency, not both",
    )

    @property
    def typical_current_a(self) -> float:
        """A typical part's supply current, A: the middle of its supply_current_a limits,
        else half the current limit (for predictions such as the self-heating's)."""
        limit = self.limits.supply_current_a
        if limit is not None and limit.low is not None and limit.high is not None:
            return 0.5 * (limit.low + limit.high)
        if limit is not None and limit.high is not None:
            return 0.5 * limit.high
        return 0.5 * self.current_limit_a

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
    def _one_consistency_rule(self) -> ProductConfig:
        if self.consistency is not None and self.limits.stop_table_consistency is not None:
            raise ValueError(
                "consistency: and limits.stop_table_consistency both judge the stop-vs-table "
                "consistency: keep consistency.false_reject_rate (the limit is derived from it) "
                "and remove limits.stop_table_consistency"
            )
        return self

    @model_validator(mode="after")
    def _part_temperature_range(self) -> ProductConfig:
        low, high = self.min_part_temperature_c, self.max_part_temperature_c
        if low is not None and high is not None and low >= high:
            raise ValueError(
                f"min_part_temperature_c {low:g} C must be below max_part_temperature_c "
                f"{high:g} C"
            )
        return self

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

class ConditionsConfig(StrictModel):
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
    revisit_c: float | None = Field(
        None, ge=1, le=20,
        description="optional: one more condition after the plan, this far from the last "
        "temperature against the way it was reached (below it after heating), at the last "
        "supply: the part's bias from the other side of its hysteresis, so that the fit "
        "measures the part's own (at least twice the product's thermal_typical."
        "hysteresis_width_c; docs/simulated-bench.md)",
    )

    @field_validator("supplies_v")
    @classmethod
    def _positive(cls, value: list[float]) -> list[float]:
        if any(v <= 0 for v in value):
            raise ValueError("supply levels must be positive volts")
        return value



class ChamberConfig(StrictModel):
    ramp_c_per_min: float = Field(5.0, ge=0, le=100, description="chamber ramp rate (0 = fastest)")
    safe_temp_c: float = Field(
        25.0, ge=0, le=50, description="setpoint the chamber goes to on any exit (0..50 C: "
        "a part must be safe to handle)"
    )
    setpoint_band_c: float = Field(0.5, gt=0, le=50, description="air within this of setpoint")
    setpoint_timeout_s: Seconds = Field(3600.0, gt=0, description="time allowed to reach setpoint")
    strategy: Literal["setpoint", "fastest"] = Field(
        "setpoint",
        description="setpoint: the chamber goes straight to each temperature; fastest: a "
        "planned setpoint profile (shaped within the overshoot bound against each die's lag and "
        "self-heating, or one overshoot held), re-planned from each part's own sensor, so the "
        "slowest die settles soonest",
    )
    max_overshoot_c: float = Field(
        15.0, ge=0, le=50, description="fastest: largest setpoint overshoot beyond the target"
    )
    air_tau_s: Seconds = Field(
        60.0, gt=0, description="fastest: the chamber air's lag behind its ramped setpoint"
    )
    replan_interval_s: Seconds = Field(
        60.0, gt=0, description="fastest: how often the profile is planned again from the readings"
    )

    @model_validator(mode="after")
    def _fastest_needs_a_ramp(self) -> ChamberConfig:
        if self.strategy == "fastest" and self.ramp_c_per_min <= 0:
            raise ValueError(
                "strategy 'fastest' plans with the chamber's ramp rate: give ramp_c_per_min > 0"
            )
        return self



class StreamConfig(StrictModel):
    max_lost_fraction: float = Field(0.001, ge=0, le=1, description="allowed lost/expected frames")
    silent_timeout_s: float = Field(
        5.0, gt=0, le=ONE_HOUR_S, description="no frames this long: part is silent"
    )
    max_lost_frames_per_window: int = Field(
        2, ge=0, le=100_000, description="lost frames allowed in any one analysis window"
    )




class ProcedureConfig(StrictModel):
    """A calibration procedure: run-wide settings and the list of steps (see docs/procedures.md).

    `steps` holds the list as written; it is parsed into step entries at validation (each
    entry's settings against its step type's model) and `plan()` expands its loops."""

    name: Name = Field(min_length=1, description="procedure name shown on the certificate")
    version: ShortName = Field("1", description="procedure version")
    description: Text = ""
    product: PathText | None = Field(
        None, description="product file, relative to this file (overridden by --product)"
    )
    output_rate_hz: Literal[50, 100, 200, 500, 1000] = Field(
        100, description="part output data rate, Hz"
    )
    conditions: ConditionsConfig
    chamber: ChamberConfig = ChamberConfig()
    stream: StreamConfig = StreamConfig()
    steps: list[dict[str, Any]] = Field(
        min_length=1,
        max_length=MAX_LIST,
        description="the steps in order: '- step: <type>' with its settings, "
        "'- for_each: condition' or '- repeat: N' with nested 'steps:' (docs/procedures.md)",
    )
    _nodes: tuple[Node, ...] = PrivateAttr(default=())

    @model_validator(mode="after")
    def _parse_steps(self, info: ValidationInfo) -> ProcedureConfig:
        if info.context and info.context.get(FIELDS_ONLY):
            return self  # the steps' problems are reported by parse_steps with file:line
        self._nodes = parse_steps(self.steps)
        return self

    @property
    def nodes(self) -> tuple[Node, ...]:
        return self._nodes

    def entries(self) -> list[StepEntry]:
        """Every step entry of the file (loops walked once)."""
        return list(entries(self._nodes))

    def entries_of(self, *type_names: str) -> list[StepEntry]:
        return [e for e in self.entries() if e.type_name in type_names]

    def planned_conditions(self, start_temp_c: float | None = None) -> list[Condition]:
        cond = self.conditions
        plan = plan_conditions(
            cond.temperatures_c, cond.supplies_v, order=cond.order, start_temp_c=start_temp_c
        )
        return with_revisit(plan, cond.revisit_c, start_temp_c)

    def plan(self, start_temp_c: float | None = None) -> list[StepType[Any]]:
        """The step instances in run order, loops unrolled."""
        return expand(self._nodes, self.planned_conditions(start_temp_c))

    @property
    def needs_table(self) -> bool:
        """Does any step need the rate table?"""
        return any(e.type.uses_table for e in self.entries())

    def settings_of(self, type_name: str) -> Any:
        """The settings of the first entry of a step type, or None."""
        found = self.entries_of(type_name)
        return found[0].settings if found else None


# the keys that mark a procedure file in the old section form (procedures.loading.legacy_procedure
# reads and converts such a file; load_procedure refuses it)
SECTION_KEYS = ("power", "stability", "bias", "rate_table", "stop_method", "positions", "fit",
                "verify")


def is_section_form(data: Any) -> bool:
    """Is this parsed YAML a procedure in the old section form?"""
    if not isinstance(data, dict):
        return False
    return any(k in data for k in SECTION_KEYS) or isinstance(data.get("steps"), dict)


def load_product(path: Path) -> tuple[ProductConfig, LoadedYaml]:
    return load_yaml_model(path, ProductConfig)


def load_procedure(path: Path) -> tuple[ProcedureConfig, LoadedYaml]:
    """Load a procedure file in the step-list form; ConfigError with file:line on any problem
    (a file in the old section form is refused with the command that converts it)."""
    loaded = read_yaml(path)
    if is_section_form(loaded.data):
        raise ConfigError(
            f"{loaded.path}:1: this procedure is in the old section form (power:, bias:, "
            "rate_table:, ... sections); the station now runs a list of steps. Convert it "
            f"with: station procedure convert {loaded.path} -o NEW.yaml"
        )
    if isinstance(loaded.data, dict) and "steps" in loaded.data:
        try:
            parse_steps(loaded.data["steps"], loaded)  # file:line for every entry's problems
        except ConfigError as exc:
            # every mistake of the file at once: the other fields' too, one line each
            raise ConfigError("\n".join(_in_file_order(
                [*_field_problems(loaded), *str(exc).splitlines()]))) from None
    return load_yaml_model(path, ProcedureConfig)


FIELDS_ONLY = "fields_only"  # validation context: check the fields, not the steps' entries


def _field_problems(loaded: LoadedYaml) -> list[str]:
    """The problems of a procedure file's fields other than its steps' entries."""
    try:
        ProcedureConfig.model_validate(loaded.data, context={FIELDS_ONLY: True})
    except ValidationError as exc:
        return format_validation_error(exc, loaded, ProcedureConfig).splitlines()
    return []


def _in_file_order(lines: list[str]) -> list[str]:
    """Problem lines (`file:line: ...`) sorted by their line, each once."""
    def line_no(text: str) -> int:
        m = re.match(r"^.*?:(\d+): ", text)
        return int(m.group(1)) if m else 0
    return sorted(dict.fromkeys(lines), key=line_no)


def consistency_judgements(procedure: ProcedureConfig) -> int:
    """How many stop-vs-table judgements the procedure can make on one part: one per
    stop_method step it runs (each judges at its condition where a rate-table fit exists), and
    one per end of the span where a ramp runs the stop method (against its fit)."""
    conditions = procedure.planned_conditions()
    steps = expand(procedure.nodes, conditions)
    return (sum(1 for step in steps if step.type_name == "stop_method")
            + sum(int(getattr(step, "stop_judgements", lambda: 0)()) for step in steps))


def product_for_procedure(product: ProductConfig, procedure: ProcedureConfig) -> ProductConfig:
    """The product as this procedure judges it: with `consistency:` the per-condition limit
    `limits.stop_table_consistency` derived for the procedure's number of judgements."""
    if product.consistency is None or product.limits.stop_table_consistency is not None:
        return product
    judgements = consistency_judgements(procedure)
    if judgements == 0:
        return product
    limits = product.limits.model_copy(
        update={"stop_table_consistency": product.consistency.limit(judgements)}
    )
    return product.model_copy(update={"limits": limits})


def check_procedure_for_product(
    procedure: ProcedureConfig,
    procedure_file: LoadedYaml,
    product: ProductConfig,
    product_file: LoadedYaml,
) -> list[str]:
    """Cross-checks of a procedure against the product it calibrates: every declared
    measurement has a limit (or is informational), every rate within the part's rated range,
    every supply level within the part's supply range. ConfigError with one line per problem,
    naming the procedure's file and line and the product's limit. Returns warnings: the
    product limits the procedure never measures."""
    product = product_for_procedure(product, procedure)
    limit_names = {k for k in LIMIT_NAMES if getattr(product.limits, k) is not None}
    measured, warnings = measurement_problems(
        procedure.nodes, limit_names, lambda p: _where(procedure_file, *p), str(product_file.path)
    )
    problems = [*measured,
                *_rate_problems(procedure, procedure_file, product, product_file),
                *_supply_problems(procedure, procedure_file, product, product_file),
                *_fit_order_problems(procedure, procedure_file, product, product_file)]
    if problems:
        raise ConfigError("\n".join(problems))
    return warnings


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
    for entry in procedure.entries():
        rates = getattr(entry.settings, "rates_dps", None) or []
        for i, rate in enumerate(rates):
            if abs(rate) > product.range_dps:
                field = ".".join(map(str, (*entry.path, "rates_dps", i)))
                out.append(
                    f"{_where(procedure_file, *entry.path, 'rates_dps', i)}: field "
                    f"{field} (step {entry.type_name}): {rate:g} deg/s is beyond the range of "
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
    for entry in procedure.entries():
        supply_v = getattr(entry.settings, "supply_v", None)
        if supply_v is not None:
            levels.append(((*entry.path, "supply_v"), supply_v))
    return [
        f"{_where(procedure_file, *path)}: field {'.'.join(map(str, path))}: {v:g} V is "
        f"outside the supply range [{low:g}, {high:g}] V of {product.product} "
        f"({product_file.path}, supply_range_v): the part could be damaged; give supply "
        "levels within the part's range"
        for path, v in levels
        if not low <= v <= high
    ]


def _fit_order_problems(
    procedure: ProcedureConfig, procedure_file: LoadedYaml, product: ProductConfig,
    product_file: LoadedYaml,
) -> list[str]:
    """A fit of an order the part cannot store, or with too few temperatures for it."""
    out = []
    temps = len(set(procedure.conditions.temperatures_c))
    for entry in procedure.entries_of("fit"):
        order = getattr(entry.settings, "order", 1)
        where = _where(procedure_file, *entry.path, "order")
        if order not in product.calibration.fit_orders:
            out.append(
                f"{where}: field {'.'.join(map(str, (*entry.path, 'order')))} (step fit): "
                f"order {order} cannot be stored by {product.product}: its calibration "
                f"registers hold orders {product.calibration.fit_orders} ({product_file.path}, "
                "calibration.fit_orders); fit to an order the part holds"
            )
        elif temps < order + 1:
            out.append(
                f"{where}: field {'.'.join(map(str, (*entry.path, 'order')))} (step fit): an "
                f"order-{order} fit needs {order + 1} temperatures, conditions.temperatures_c "
                f"gives {temps}; add temperatures or lower the order"
            )
    return out
