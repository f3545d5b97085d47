"""What the steps record: the typed sections of `record.analysis` and `record.verification`.

Each step type names its section's model as `Results` (procedures/steps/registry.py), as it
names its `Settings`; the engine's own sections are here too. A section refuses a key it
does not declare (extra="forbid"): a renamed field fails at the writer (mypy, or validation),
never silently as "not recorded" on the certificate.

JSON is what the format-1 dicts were: a field the writer did not set is left out (not
written as null), and an `Analysis` section nobody wrote is left out. Format-1 records are
read through `analysis_from_format_1` / `verification_from_format_1`: keys a section does
not declare are dropped, and a section (or a condition's entry) that does not validate is
dropped with a log line, so the certificate shows it as not recorded as it did before.
Floats are `float | None` where the writer may give NaN: pydantic writes NaN as null.
"""

from __future__ import annotations

import logging
from typing import Any

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    SerializerFunctionWrapHandler,
    ValidationError,
    ValidationInfo,
    model_serializer,
    model_validator,
)

log = logging.getLogger(__name__)

FORMAT_1 = "format-1"  # validation context key: the section comes from a format-1 record

Num = float | None  # a number the writer may give as NaN (written null)
Nums = list[float | None]


class Section(BaseModel):
    """A typed part of the record written by one writer: unknown keys refused; the fields
    the writer left out stay out of the JSON."""

    model_config = ConfigDict(extra="forbid")

    def __contains__(self, item: object) -> bool:
        # A pydantic model iterates as (name, value) pairs, so `"name" in section` would be
        # False for every name, and a check written that way could never fail: refused.
        raise TypeError(f"`in` on {type(self).__name__} is always False; compare the field "
                        "(section.name is None) or its model_fields_set")

    @model_validator(mode="before")
    @classmethod
    def _drop_unknown_in_format_1(cls, data: Any, info: ValidationInfo) -> Any:
        if isinstance(data, dict) and info.context and info.context.get(FORMAT_1):
            return {k: v for k, v in data.items() if k in cls.model_fields}
        return data

    @model_serializer(mode="wrap")
    def _as_written(self, handler: SerializerFunctionWrapHandler) -> Any:
        data = handler(self)
        if not isinstance(data, dict):
            return data
        return {k: v for k, v in data.items() if k in self.model_fields_set}


# ------------------------------------------------------------------ the steps' sections


class StopMove(Section):
    start_s: Num = None  # the integration window, fixture clock
    end_s: Num = None
    measured_angle_deg: Num = None
    peak_rate_dps: Num = None  # manual_stop only
    over_range_samples: int | None = None  # manual_stop only
    scale_correction: Num = None


class StopMethodResults(Section):
    """analysis.stop_method[<condition>] (steps stop and manual_stop); the same keys as
    `station analyze stop-method --json`. Windows on the fixture clock."""

    method: str | None = None  # "manual_stop" for a hand-turned fixture
    bias_dps: Num = None
    bias_correction_dps: Num = None
    scale_correction: Num = None
    scale: Num = None
    u_scale: Num = None
    reference_angle_deg: Num = None
    u_reference_angle_deg: Num = None
    reference: str | None = None
    static_windows: list[list[float]] = Field(default_factory=list)  # [[start_s, end_s]]
    moves: list[StopMove] = Field(default_factory=list)
    warnings: list[str] = Field(default_factory=list)


class RateTableResults(Section):
    """analysis.rate_table[<condition>] (step sweep): one point per plateau."""

    rate_in_dps: Nums = Field(default_factory=list)
    u_rate_in_dps: Nums = Field(default_factory=list)
    rate_out_dps: Nums = Field(default_factory=list)
    u_rate_out_dps: Nums = Field(default_factory=list)
    residual_dps: Nums = Field(default_factory=list)  # output minus the fitted line
    scale: Num = None
    u_scale: Num = None
    bias_dps: Num = None
    u_bias_dps: Num = None
    nonlinearity_pct_fs: Num = None
    asymmetry_ppm: Num = None


class AllanResults(Section):
    """analysis.allan (step bias, its first condition)."""

    condition: str = ""
    tau_s: Nums = Field(default_factory=list)
    adev_dps: Nums = Field(default_factory=list)
    arw_deg_per_sqrt_h: Num = None
    bias_instability_deg_per_h: Num = None
    rate_random_walk_deg_per_h_per_sqrt_h: Num = None
    record_s: Num = None


class StabilityResults(Section):
    """analysis.stability[<condition>] (step thermal): the criterion and how it was met."""

    window_s: Num = None  # judged over the last window_s
    max_rate_c_per_min: Num = None  # largest |slope| allowed in the window
    band_c: Num = None  # largest peak-to-peak allowed in the window
    tolerance_c: Num = None  # within this of the setpoint (None: not asked)
    time_to_stability_s: Num = None
    stable: bool | None = None
    slope_c_per_min: Num = None
    measured_band_c: Num = None
    die_temperature_c: Num = None
    stable_at_station_s: Num = None
    stable_at_fixture_s: Num = None
    condition_set_station_s: Num = None
    measurement_start_station_s: Num = None
    # the `fastest` strategy's summary (procedures/thermal/thermal_control.py)
    strategy: str | None = None
    plan: str | None = None
    die_tau_s: Num = None
    overshoot_c: Num = None
    hold_s: Num = None
    predicted_settle_s: Num = None
    replans: int | None = None
    self_heating_c_per_w: Num = None
    # how the window was judged: "before" the measurement (the default), "after" it
    # (overlap_measurement: the window judged over the measurement), or "predicted" (no wait at
    # a supply change whose predicted self-heating change meets the criterion)
    judged: str | None = None
    entry_s: Num = None  # overlap: the shorter span each die met the criterion over first
    predicted_change_c: Num = None  # no wait: the part's predicted self-heating change
    after_slope_c_per_min: Num = None  # overlap: the window judged after the measurement
    after_band_c: Num = None
    judged_until_station_s: Num = None  # overlap: the end of the span judged afterwards


class FirstMeasurement(Section):
    """A measurement of a first attempt, taken off the judged record (measured again)."""

    name: str
    condition: str | None = None
    value: Num = None
    outcome: str = ""
    low: Num = None
    high: Num = None


class MeasuredAgainResults(Section):
    """One entry of analysis.measured_again (step thermal, overlap_measurement): a
    condition measured again because its stability window, judged after the measurement,
    failed; the first attempt's stability and measurements as they were."""

    condition: str
    why: str = ""
    first_stability: StabilityResults | None = None
    first: list[FirstMeasurement] = Field(default_factory=list)


class FitCondition(Section):
    name: str
    bias_temp_c: Num = None
    scale_temp_c: Num = None
    supply_v: Num = None
    bias_dps: Num = None  # as fitted: the measured bias plus the hysteresis correction
    u_bias_dps: Num = None  # the measurement's own (k=1)
    scale: Num = None
    u_scale: Num = None
    # only when the product declares its hysteresis (procedures.analysis.hysteresis):
    # the state the bias was measured in (+1 heated .. -1 cooled), the correction added to
    # it and the correction's k=1 uncertainty (correlated between the conditions)
    hysteresis_state: Num = None
    hysteresis_correction_dps: Num = None
    u_hysteresis_correction_dps: Num = None


class HysteresisResults(Section):
    """analysis.fit.hysteresis: the part's own hysteresis, fitted when its conditions reach
    both sides (procedures.analysis.hysteresis.own_hysteresis), against the product's."""

    hysteresis_dps: Num = None
    u_hysteresis_dps: Num = None  # k=1
    typical_dps: Num = None
    normalised: Num = None  # (own - typical) / sqrt(u^2 + sigma^2)
    beyond_typical: bool | None = None  # |normalised| > 3: outside the declared spread


class FitResults(Section):
    """analysis.fit (step fit): the points the calibration was fitted to."""

    source: str = ""
    order: int | None = None  # only above first order
    conditions: list[FitCondition] = Field(default_factory=list)
    hysteresis: HysteresisResults | None = None  # only with a revisit (both sides)


class FitCoefficient(Section):
    name: str
    value: Num = None
    uncertainty_k2: Num = None
    units: str = ""


class TemperaturePoint(Section):
    condition: str
    bias_temp_c: Num = None
    scale_temp_c: Num = None
    supply_v: Num = None
    bias_dps: Num = None
    u_bias_dps: Num = None
    scale: Num = None
    u_scale: Num = None


class TemperatureFitResults(Section):
    """analysis.temperature_fit (step fit, three or more temperatures or above first
    order): what reports/cert_temperature_fit.py draws."""

    order: int
    reference_temperature_c: float
    reference_supply_v: float
    coefficients: list[FitCoefficient] = Field(default_factory=list)
    bias_params: Nums = Field(default_factory=list)
    scale_params: Nums = Field(default_factory=list)
    bias_chi2: Num = None
    scale_chi2: Num = None
    dof: int | None = None
    points: list[TemperaturePoint] = Field(default_factory=list)


class RampResults(Section):
    """analysis.ramp (step ramp_calibration): the ramp's plateaus and what the fit learned
    of the part's thermal behaviour (procedures/analysis/ramp_fit.py); k=1 unless named."""

    low_c: float
    high_c: float
    die_min_c: Num = None
    die_max_c: Num = None
    turned_at_station_s: Num = None  # the chamber turned from heating to cooling
    end_turn_station_s: Num = None  # turned to the end setpoint (then: the dies to rest)
    duration_s: Num = None
    element_tau_s: Num = None  # the element's lag behind the sensor (null: not told)
    u_element_tau_s: Num = None
    tau_bound_s: Num = None  # the lag the lag-correction error is computed at
    max_element_tau_s: Num = None  # refused beyond
    gradient_dps_per_c_per_min: Num = None
    hysteresis_dps: Num = None
    u_hysteresis_dps: Num = None
    chi2_per_dof: Num = None
    lag_error_k2: dict[str, float] = Field(default_factory=dict)  # added to each U
    refused: str | None = None
    time_s: Nums = Field(default_factory=list)  # plateau mid-times, station s
    rate_in_dps: Nums = Field(default_factory=list)
    rate_out_dps: Nums = Field(default_factory=list)
    u_rate_out_dps: Nums = Field(default_factory=list)
    die_temp_c: Nums = Field(default_factory=list)
    die_rate_c_per_min: Nums = Field(default_factory=list)
    supply_v: Nums = Field(default_factory=list)  # measured at each plateau's sweep
    supplies_v: Nums = Field(default_factory=list)  # the levels set, alternated each sweep
    heating: list[bool] = Field(default_factory=list)  # the chamber's half
    residual_dps: Nums = Field(default_factory=list)
    # the rate set at the reference point (procedures/analysis/ramp_linearity.py)
    nonlinearity_pct_fs: Num = None
    asymmetry_ppm: Num = None
    linearity_rate_in_dps: Nums = Field(default_factory=list)  # one per commanded rate
    linearity_residual_dps: Nums = Field(default_factory=list)


class RampStopEnd(Section):
    """One stop-method record at one end of the ramp (procedures/steps/ramp_stop.py) and its
    comparison with the ramp fit's scale law there; k=1 unless named."""

    label: str  # ramp_top | ramp_bottom: raw.h5 segments' condition, the measurement's
    end: str  # top | bottom
    station_s: Num = None  # the record's start
    die_temp_c: Num = None  # the die's sensor, mean over the record
    element_temp_c: Num = None  # the law is taken here: the die's less the lag x its rate
    die_rate_c_per_min: Num = None
    supply_v: Num = None
    stop: StopMethodResults
    ramp_scale: Num = None  # the fitted scale law at element_temp_c, supply_v
    u_ramp_scale: Num = None
    normalised_difference: Num = None  # (stop scale - ramp_scale) / combined u


class RampStopResults(Section):
    """analysis.ramp_stop (step ramp_calibration with stop_method): one entry per end."""

    ends: list[RampStopEnd] = Field(default_factory=list)


class ProgrammingResults(Section):
    """analysis.programming (steps program, program_three_axis)."""

    programmed: bool
    reason: str | None = None  # why not


class RemeasuredFirst(Section):
    value: Num = None
    outcome: str = ""
    low: Num = None
    high: Num = None
    scale_stop: Num = None
    u_scale_stop: Num = None


class RemeasuredSecond(Section):
    value: Num = None
    outcome: str = ""


class RemeasuredResults(Section):
    """One entry of analysis.remeasured (step stop): a judgement measured once more."""

    measurement: str
    condition: str | None = None
    why: str = ""
    first: RemeasuredFirst | None = None
    second: RemeasuredSecond | None = None


class WarmUpResults(Section):
    """analysis.warm_up[<condition or "run">] (step warm_up)."""

    criterion: str = ""
    warm_up_time_s: Num = None
    warm_up_time_uncertainty_k2: Num = None
    band_dps: Num = None
    final_bias_dps: Num = None
    amplitude_dps: Num = None
    tau_s: Num = None
    resolved: bool | None = None
    settled_in_record: bool | None = None
    record_end_s: Num = None
    window_t_s: Nums = Field(default_factory=list)
    window_bias_dps: Nums = Field(default_factory=list)


class TurnOnResults(Section):
    """analysis.turn_on_repeatability[<condition or "run">] (step turn_on_repeatability)."""

    repeatability_dps: Num = None
    repeatability_uncertainty_k2: Num = None
    mean_bias_dps: Num = None
    noise_floor_dps: Num = None
    excess_dps: Num = None
    interval_95_dps: Nums = Field(default_factory=list)
    resolved: bool | None = None
    biases_dps: Nums = Field(default_factory=list)
    bias_uncertainties_dps: Nums = Field(default_factory=list)
    off_s: Num = None
    settle_s: Num = None
    dwell_s: Num = None


class PositionWindow(Section):
    """One static window of analysis.positions[<condition>] (step positions)."""

    angle_cmd_deg: Num = None
    angle_deg: Num = None
    start_s: Num = None
    end_s: Num = None
    mean_dps: Num = None
    samples: int | None = None


class ThreeAxisWindow(Section):
    """One window of analysis.three_axis_windows (step cube; procedures.analysis.three_axis
    .Window as a dict)."""

    face: str
    table_rate_dps: Num = None
    rate_dps: Nums = Field(default_factory=list)
    u_rate_dps: Nums = Field(default_factory=list)
    accel_mps2: Nums = Field(default_factory=list)
    temp_c: Num = None
    supply_v: Num = None
    condition: str = ""
    start_s: Num = None
    end_s: Num = None
    bias_instability_dps: Num = None  # the part's, each axis shares its wander
    rate_random_walk_dps_per_sqrt_s: Num = None


# ------------------------------------------------------------------ the engine's sections


class PlanResults(Section):
    """analysis.plan (the engine): what the run was planned to do."""

    estimated_station_s: Num = None
    steps: list[str] = Field(default_factory=list)  # the step types planned, in first order


class InstrumentSafeResults(Section):
    name: str
    safe: bool
    detail: str = ""
    attempts: int = 0
    read_back: bool = True
    safe_at_station_s: Num = None
    errors: list[str] = Field(default_factory=list)


class SafeStateResults(Section):
    """analysis.start_safe_state and .safe_state_report (procedures.engine.safe_state)."""

    all_safe: bool
    started_station_s: Num = None
    finished_station_s: Num = None
    safe_temp_c: Num = None
    summary: str = ""
    instruments: dict[str, InstrumentSafeResults] = Field(default_factory=dict)


class StreamResults(Section):
    frames_ok: int = 0
    frames_lost: int = 0
    frames_corrupted: int = 0


# ------------------------------------------------------------------ verification


class VerificationRow(Section):
    condition: str
    rate_in_dps: Num = None
    error_dps: Num = None
    error_pct: Num = None
    u_error_pct_k2: Num = None


class Verification(Section):
    """record.verification (steps verify, verify_stop, manual_stop's verification)."""

    method: str | None = None  # stop_method | manual_stop; absent: the rate table
    residuals: list[VerificationRow] = Field(default_factory=list)
    residual_bias_dps: Num = None
    max_error_pct: Num = None
    max_abs_error_pct_fs: Num = None
    supply_v: Num = None
    die_temperature_c: Num = None
    reference: str | None = None
    reference_angle_deg: Num = None
    u_reference_angle_deg: Num = None
    passed: bool | None = None


# ------------------------------------------------------------------ the whole analysis


class Analysis(Section):
    """record.analysis: every section optional (a procedure runs the steps it lists)."""

    plan: PlanResults | None = None
    start_safe_state: SafeStateResults | None = None
    stability: dict[str, StabilityResults] = Field(default_factory=dict)
    allan: AllanResults | None = None
    rate_table: dict[str, RateTableResults] = Field(default_factory=dict)
    stop_method: dict[str, StopMethodResults] = Field(default_factory=dict)
    remeasured: list[RemeasuredResults] = Field(default_factory=list)
    measured_again: list[MeasuredAgainResults] = Field(default_factory=list)
    warm_up: dict[str, WarmUpResults] = Field(default_factory=dict)
    turn_on_repeatability: dict[str, TurnOnResults] = Field(default_factory=dict)
    positions: dict[str, list[PositionWindow]] = Field(default_factory=dict)
    three_axis_windows: list[ThreeAxisWindow] | None = None
    fit: FitResults | None = None
    ramp: RampResults | None = None
    ramp_stop: RampStopResults | None = None
    temperature_fit: TemperatureFitResults | None = None
    programming: ProgrammingResults | None = None
    marginal_measurements: list[str] | None = None
    not_measured: list[str] | None = None
    safe_state: dict[str, str] | None = None  # the legacy one-line-per-instrument form
    safe_state_report: SafeStateResults | None = None
    stop_requested_station_s: Num = None
    stream: StreamResults | None = None

    @model_serializer(mode="wrap")
    def _as_written(self, handler: SerializerFunctionWrapHandler) -> Any:
        """A section is written when set, or filled in place (a per-condition dict)."""
        data = handler(self)
        if not isinstance(data, dict):
            return data
        return {k: v for k, v in data.items()
                if k in self.model_fields_set or (v is not None and v != {} and v != [])}


# ------------------------------------------------------------------ format 1


PER_CONDITION = ("stability", "rate_table", "stop_method", "warm_up", "turn_on_repeatability",
                 "positions")
LISTS = ("remeasured", "measured_again", "three_axis_windows")


def analysis_from_format_1(raw: Any) -> Analysis:
    """A format-1 record's free `analysis` dict as typed sections; whatever does not fit
    (an unknown key, a condition's entry that does not validate) is dropped, as the reports
    of format 1 skipped it."""
    if not isinstance(raw, dict):
        return Analysis()
    out: dict[str, Any] = {}
    for key, value in raw.items():
        if key not in Analysis.model_fields:
            log.info("format-1 record: analysis.%s is not a section of format 2; dropped", key)
            continue
        if key in PER_CONDITION:
            out[key] = _per_condition(key, value)
        elif key in LISTS:
            out[key] = _list(key, value)
        else:
            out[key] = value
    try:
        return Analysis.model_validate(out, context={FORMAT_1: True})
    except ValidationError:
        kept = {k: v for k, v in out.items() if _section_ok(k, v)}
        return Analysis.model_validate(kept, context={FORMAT_1: True})


def _section_ok(key: str, value: Any) -> bool:
    try:
        Analysis.model_validate({key: value}, context={FORMAT_1: True})
    except ValidationError as exc:
        log.warning("format-1 record: analysis.%s dropped (%s)", key, exc.errors()[0]["msg"])
        return False
    return True


def _per_condition(key: str, value: Any) -> dict[str, Any]:
    if not isinstance(value, dict):
        return {}
    return {c: v for c, v in value.items() if _section_ok(key, {c: v})}


def _list(key: str, value: Any) -> list[Any]:
    if not isinstance(value, list):
        return []
    return [v for v in value if _section_ok(key, [v])]


def verification_from_format_1(raw: Any) -> Verification | None:
    """A format-1 record's `verification` dict, typed; rows that do not validate dropped."""
    if not isinstance(raw, dict):
        return None
    data = dict(raw)
    rows = data.get("residuals")
    data["residuals"] = [r for r in rows if _row_ok(r)] if isinstance(rows, list) else []
    if "residuals" not in raw:
        data.pop("residuals")
    try:
        return Verification.model_validate(data, context={FORMAT_1: True})
    except ValidationError as exc:
        log.warning("format-1 record: verification dropped (%s)", exc.errors()[0]["msg"])
        return None


def _row_ok(row: Any) -> bool:
    try:
        VerificationRow.model_validate(row, context={FORMAT_1: True})
    except ValidationError:
        return False
    return True
