"""First-order bias and scale fit over the conditions (procedures.analysis.temp_supply_fit)."""

from __future__ import annotations

import math
from dataclasses import dataclass

from procedures.analysis.errors import AnalysisError
from procedures.analysis.temp_supply_fit import ConditionMeasurement, fit_temp_supply
from procedures.engine import ConditionResult, PartRun, RunContext, condition_record
from procedures.record import Calibration, Verdict
from procedures.steps.base import BaseStep

COEFF_UNITS = {
    "bias_temp_coeff_dps_per_c": "deg/s/C",
    "scale_temp_coeff_per_c": "1/C",
    "bias_supply_coeff_dps_per_v": "deg/s/V",
    "scale_supply_coeff_per_v": "1/V",
}


def scale_estimate(source: str, res: ConditionResult) -> tuple[float, float]:
    """(scale, k=1 uncertainty) at one condition from the chosen source."""
    table = None if res.table_fit is None else (res.table_fit.scale, res.table_fit.u_scale)
    stop = None if res.stop is None else (res.stop["scale"], res.stop["u_scale"])
    if source == "rate_table" or (source == "both" and stop is None):
        if table is None:
            raise AnalysisError(f"{res.name}: no rate-table scale to fit")
        return table
    if source == "stop_method" or table is None:
        if stop is None:
            raise AnalysisError(f"{res.name}: no stop-method scale to fit")
        return stop
    w1, w2 = 1 / table[1] ** 2, 1 / stop[1] ** 2
    return (w1 * table[0] + w2 * stop[0]) / (w1 + w2), math.sqrt(1 / (w1 + w2))


@dataclass
class Fit(BaseStep):
    name: str = "fit"
    policy: str = "fit"

    def main(self, ctx: RunContext) -> None:
        ctx.each(lambda part: self._fit(ctx, part))

    def _fit(self, ctx: RunContext, part: PartRun) -> None:
        source = ctx.procedure.fit.source
        conds = []
        try:
            for res in part.conditions.values():
                if res.bias_dps is None or res.u_bias_dps is None or res.die_temperature_c is None:
                    raise AnalysisError(f"{res.name}: the bias was not measured")
                scale, u_scale = scale_estimate(source, res)
                conds.append(ConditionMeasurement(
                    temp_c=res.die_temperature_c,
                    supply_v=res.supply_measured_v if res.supply_measured_v else res.supply_v,
                    bias_dps=res.bias_dps, u_bias_dps=res.u_bias_dps,
                    scale=scale, u_scale=u_scale))
            fit = fit_temp_supply(conds, ctx.product.reference_temperature_c,
                                  ctx.product.reference_supply_v)
        except AnalysisError as exc:
            ctx.drop(part, Verdict.ERROR, f"first-order fit: {exc}")
            return
        part.fit = fit
        part.record.conditions = [condition_record(r) for r in part.conditions.values()]
        part.record.calibration = Calibration.model_validate(fit.as_calibration_dict())
        part.record.analysis["fit"] = {"source": source, "conditions": [
            {"name": r.name, "temp_c": c.temp_c, "supply_v": c.supply_v, "bias_dps": c.bias_dps,
             "u_bias_dps": c.u_bias_dps, "scale": c.scale, "u_scale": c.u_scale}
            for r, c in zip(part.conditions.values(), conds, strict=True)]}
        co = fit.coefficients
        for name, units in COEFF_UNITS.items():
            ctx.measure(part, name, getattr(co, name), units=units,
                        uncertainty_k2=fit.uncertainty_k2(name),
                        description="first-order coefficient")
