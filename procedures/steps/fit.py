"""First-order bias and scale fit over the conditions (procedures.analysis.temp_supply_fit)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any, Literal

from pydantic import Field

from procedures.analysis.errors import AnalysisError
from procedures.analysis.hysteresis import (
    HysteresisCorrection,
    OwnHysteresis,
    both_sides,
    correction,
    own_correction,
    own_hysteresis,
)
from procedures.analysis.temp_supply_fit import (
    ConditionMeasurement,
    FirstOrderCoefficients,
    TempSupplyFit,
    fit_temp_supply,
)
from procedures.runtime.record import Calibration, Verdict
from procedures.runtime.results import FitCondition, FitResults, HysteresisResults
from procedures.runtime.run_context import RunContext
from procedures.runtime.run_parts import ConditionResult, PartRun, condition_record
from procedures.steps.fit_order import (
    declared_beyond_first_order,
    fit_beyond_first_order,
    record_first_order_summary,
)
from procedures.steps.registry import Declared, Provided, StepSettings, StepType

COEFF_UNITS = {
    "bias_temp_coeff_dps_per_c": "deg/s/C",
    "scale_temp_coeff_per_c": "1/C",
    "bias_supply_coeff_dps_per_v": "deg/s/V",
    "scale_supply_coeff_per_v": "1/V",
}


def scale_estimate(source: str, res: ConditionResult) -> tuple[float, float]:
    """(scale, k=1 uncertainty) at one condition from the chosen source."""
    table = None if res.table_fit is None else (res.table_fit.scale, res.table_fit.u_scale)
    stop = None if res.stop is None else (res.stop.scale, res.stop.u_scale)
    if source == "rate_table" or (source == "both" and stop is None):
        if table is None:
            raise AnalysisError(f"{res.name}: no rate-table scale to fit")
        return table
    if source == "stop_method" or table is None:
        if stop is None:
            raise AnalysisError(f"{res.name}: no stop-method scale to fit")
        return stop
    if stop is None:
        return table
    w1, w2 = 1 / table[1] ** 2, 1 / stop[1] ** 2
    return (w1 * table[0] + w2 * stop[0]) / (w1 + w2), math.sqrt(1 / (w1 + w2))


class FitSettings(StepSettings):
    source: Literal["rate_table", "stop_method", "both"] = Field(
        "rate_table",
        description="which scale estimate feeds the fit (both: weighted by uncertainty)",
    )
    order: Literal[1, 2, 3] = Field(
        1,
        description="order of the fit in temperature (first order in supply); 2 and 3 need "
        "that many + 1 temperatures and a part whose product file lists the order in "
        "calibration.fit_orders (procedures.steps.fit_order)",
    )


class Fit(StepType[FitSettings]):
    """First-order bias and scale fit over the conditions measured so far."""

    type_name = "fit"
    Settings = FitSettings
    provides = frozenset({Provided.FIT})
    Results = FitResults

    @classmethod
    def requires(cls, settings: Any) -> set[Provided]:
        need = {"rate_table": {Provided.SCALE_TABLE}, "stop_method": {Provided.SCALE_STOP},
                "both": {Provided.SCALE_TABLE, Provided.SCALE_STOP}}[settings.source]
        return {Provided.BIAS, *need}

    @classmethod
    def measurements(cls, settings: Any) -> list[Declared]:
        return [Declared(name, units, "first-order coefficient")
                for name, units in COEFF_UNITS.items()] + declared_beyond_first_order(
                    settings.order) + [
            Declared("hysteresis_dps", "deg/s", "the part's own hysteresis (a revisit's "
                     "conditions reach both sides)", informational=True, optional=True)]

    def main(self, ctx: RunContext) -> None:
        ctx.parts.each(lambda part: self._fit(ctx, part))

    def _fit(self, ctx: RunContext, part: PartRun) -> None:
        source = self.settings.source
        try:
            t0, v0 = ctx.product.reference_temperature_c, ctx.product.reference_supply_v
            typical = ctx.product.thermal_typical
            raw = fit_inputs(part, source, 0.0 if typical is None else typical.element_tau_s)
            hyst = hysteresis_corrections(ctx, part, raw["bias"], (t0, v0))
            by_kind = corrected(raw, part, hyst.corrections)
            if self.settings.order > 1:
                fit_beyond_first_order(ctx, part, self.settings.order,
                                       corrected(raw, part, hyst.corrections, folded=True),
                                       t0, v0, source)
                return
            # bias paired with the die temperature of its own windows, scale with its own
            fit_b = fit_temp_supply(by_kind["bias"], t0, v0)
            fit_s = fit_temp_supply(by_kind["scale"], t0, v0)
        except AnalysisError as exc:
            ctx.parts.drop(part, Verdict.ERROR, f"first-order fit: {exc}")
            return
        cb, cs = fit_b.coefficients, fit_s.coefficients
        coefficients = replace(
            cb,
            scale=cs.scale,
            scale_temp_coeff_per_c=cs.scale_temp_coeff_per_c,
            scale_supply_coeff_per_v=cs.scale_supply_coeff_per_v,
        )
        part.fit = CombinedFit(coefficients, fit_b, fit_s)
        part.record.conditions = [condition_record(r) for r in part.conditions.values()]
        part.record.calibration = _calibration(fit_b, fit_s)
        record_first_order_summary(part, by_kind, t0, v0)
        part.record.analysis.fit = FitResults(
            source=source,
            conditions=[
                fit_point(r.name, b, sc, hyst.corrections.get(r.name))
                for r, b, sc in zip(
                    part.conditions.values(), by_kind["bias"], by_kind["scale"], strict=True
                )
            ],
        )
        if hyst.own is not None:
            record_own_hysteresis(ctx, part, hyst.own)
        for name, units in COEFF_UNITS.items():
            fit = fit_b if name.startswith("bias") else fit_s
            ctx.records.measure(
                part,
                name,
                getattr(coefficients, name),
                units=units,
                uncertainty_k2=fit.uncertainty_k2(name),
                description="first-order coefficient",
            )


@dataclass(frozen=True)
class Hysteresis:
    """Each condition's hysteresis correction (by name) and, from conditions reached from
    both sides, the part's own hysteresis (None: the product's typical value was used)."""

    corrections: dict[str, HysteresisCorrection]
    own: OwnHysteresis | None = None


def hysteresis_corrections(ctx: RunContext, part: PartRun, raw: list[ConditionMeasurement],
                           reference: tuple[float, float]) -> Hysteresis:
    """The corrections from the state each bias was measured in: with the part's own h when
    the conditions reach both sides (a revisit), else with the product's declared typical
    h and spread; none when the product declares none (or the states were not followed)."""
    typical = ctx.product.thermal_typical
    states = [res.hysteresis_state for res in part.conditions.values()]
    if typical is None or any(s is None for s in states):
        return Hysteresis({})
    known = [float(s) for s in states if s is not None]
    names = list(part.conditions)
    if not both_sides(known):
        return Hysteresis({n: correction(s, typical.hysteresis_dps, typical.hysteresis_sigma_dps)
                           for n, s in zip(names, known, strict=True)})
    own = own_hysteresis(raw, known, (typical.hysteresis_dps, typical.hysteresis_sigma_dps),
                         reference)
    return Hysteresis({n: own_correction(s, own) for n, s in zip(names, known, strict=True)},
                      own)


def record_own_hysteresis(ctx: RunContext, part: PartRun, own: OwnHysteresis) -> None:
    """The part's own hysteresis on the record; beyond the product's declared spread, a
    warning the run's events and the record's analysis.fit.hysteresis both carry."""
    ctx.records.measure(part, "hysteresis_dps", own.hysteresis_dps, units="deg/s",
                        uncertainty_k2=2 * own.u_hysteresis_dps,
                        description="bias after heating minus after cooling (own)")
    fit = part.record.analysis.fit
    if fit is not None:
        fit.hysteresis = HysteresisResults(
            hysteresis_dps=own.hysteresis_dps, u_hysteresis_dps=own.u_hysteresis_dps,
            typical_dps=own.typical_dps, normalised=own.normalised,
            beyond_typical=own.beyond_typical,
        )
    if own.beyond_typical:
        ctx.records.event(
            f"socket {part.socket}: hysteresis {own.hysteresis_dps:+.4f} deg/s is "
            f"{own.normalised:+.1f} sigma from the product's typical {own.typical_dps:g}: "
            "fitted from the part's own data (its coefficients hold), but outside the "
            "declared spread (product thermal_typical)", level="WARNING", parts=[part])


def fit_inputs(part: PartRun, source: str, lag_s: float = 0.0
               ) -> dict[str, list[ConditionMeasurement]]:
    """Each condition's bias and scale with the die temperature of its own windows, carried
    to the sensing element's by the product's typical lag `lag_s` (the element trails the
    sensor by slope x lag while the die still creeps); raises AnalysisError naming what a
    condition lacks."""
    by_kind: dict[str, list[ConditionMeasurement]] = {"bias": [], "scale": []}
    for res in part.conditions.values():
        if res.bias_dps is None or res.u_bias_dps is None:
            raise AnalysisError(f"{res.name}: the bias was not measured")
        scale, u_scale = scale_estimate(source, res)
        supply = res.supply_measured_v if res.supply_measured_v else res.supply_v
        for kind, cond_list in by_kind.items():
            temp = res.temperature_for(kind, lag_s)
            if temp is None:
                raise AnalysisError(f"{res.name}: no die temperature recorded")
            cond_list.append(
                ConditionMeasurement(
                    temp_c=temp,
                    supply_v=supply,
                    bias_dps=res.bias_dps,
                    u_bias_dps=res.u_bias_dps,
                    scale=scale,
                    u_scale=u_scale,
                )
            )
    return by_kind


def corrected(by_kind: dict[str, list[ConditionMeasurement]], part: PartRun,
              corrections: dict[str, HysteresisCorrection], folded: bool = False
              ) -> dict[str, list[ConditionMeasurement]]:
    """The biases carried to the hysteresis midline, each with the correction's error as
    common to the conditions (temp_supply_fit), or `folded` into its own u (for the fits
    above first order, which weigh the conditions as independent)."""
    out: dict[str, list[ConditionMeasurement]] = {}
    for kind, conds in by_kind.items():
        out[kind] = []
        for name, c in zip(part.conditions, conds, strict=True):
            corr = corrections.get(name)
            if corr is None:
                out[kind].append(c)
            elif folded:
                out[kind].append(replace(
                    c, bias_dps=c.bias_dps + corr.correction_dps,
                    u_bias_dps=math.hypot(c.u_bias_dps, corr.u_correction_dps)))
            else:
                out[kind].append(replace(c, bias_dps=c.bias_dps + corr.correction_dps,
                                         u_bias_common_dps=corr.u_common_dps))
    return out


def fit_point(name: str, b: ConditionMeasurement, sc: ConditionMeasurement,
                   corr: HysteresisCorrection | None) -> FitCondition:
    """One point the calibration was fitted to: its bias as fitted (the hysteresis
    correction applied), the correction and the state it came from when there is one."""
    extra: dict[str, float] = {} if corr is None else {
        "hysteresis_state": corr.state,
        "hysteresis_correction_dps": corr.correction_dps,
        "u_hysteresis_correction_dps": corr.u_correction_dps,
    }
    return FitCondition(
        name=name, bias_temp_c=b.temp_c, scale_temp_c=sc.temp_c, supply_v=b.supply_v,
        bias_dps=b.bias_dps, u_bias_dps=b.u_bias_dps, scale=b.scale, u_scale=b.u_scale,
        **extra,
    )


def _calibration(fit_b: TempSupplyFit, fit_s: TempSupplyFit) -> Calibration:
    """The record's calibration: bias terms from the bias fit, scale terms from the scale's."""
    cal = {k: v for k, v in fit_b.as_calibration_dict().items() if not k.startswith("scale")}
    cal.update({k: v for k, v in fit_s.as_calibration_dict().items() if k.startswith("scale")})
    inter_b, inter_s = fit_b.interaction, fit_s.interaction
    if inter_b is not None and inter_s is not None:
        cal["interaction_check"] = {
            **{k: v for k, v in inter_b.as_dict().items() if not k.startswith("scale")},
            **{k: v for k, v in inter_s.as_dict().items() if k.startswith("scale")},
        }
    return Calibration.model_validate(cal)


@dataclass(frozen=True)
class CombinedFit:
    """Bias terms from the bias-temperature fit, scale terms from the scale-temperature fit."""

    coefficients: FirstOrderCoefficients
    bias_fit: TempSupplyFit
    scale_fit: TempSupplyFit
    registers_beyond_first_order: dict[str, float] = field(default_factory=dict)  # none here
