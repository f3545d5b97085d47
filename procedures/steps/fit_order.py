"""The fit step's `order: 2 | 3`: bias and scale against temperature beyond first order.

`procedures.steps.fit` keeps today's first-order path; with `order` above 1 it hands its
conditions here (procedures.analysis.temp_fit does the fitting). The part's `fit` then holds
the order-N values of the six first-order registers and the higher-order registers for the
program step; the record's calibration block gains the higher-order terms and `fit_order`
(extra keys, so older readers still load it); `analysis.temperature_fit` feeds the
certificate's section (reports/cert_temperature_fit.py), written too for a first-order fit
over three or more temperatures.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

from drivers.protocols import CalibrationRegisters
from procedures.analysis.errors import AnalysisError
from procedures.analysis.temp_fit import (
    HIGHER_BIAS_NAMES,
    HIGHER_SCALE_NAMES,
    UNITS,
    TemperatureFit,
    fit_temperature,
    record_summary,
)
from procedures.analysis.temp_supply_fit import ConditionMeasurement, FirstOrderCoefficients
from procedures.runtime.record import Calibration, Verdict
from procedures.runtime.results import FitResults, TemperatureFitResults
from procedures.runtime.run_context import RunContext
from procedures.runtime.run_parts import PartRun, condition_record
from procedures.steps.registry import Declared

# record name of each higher-order term -> the calibration register it is programmed into
REGISTER_OF = {
    "bias_temp_coeff2_dps_per_c2": "bias_tc2_dps_per_c2",
    "bias_temp_coeff3_dps_per_c3": "bias_tc3_dps_per_c3",
    "scale_temp_coeff2_per_c2": "scale_tc2_per_c2",
    "scale_temp_coeff3_per_c3": "scale_tc3_per_c3",
}
FIRST_ORDER_BIAS = ("bias_dps", "bias_temp_coeff_dps_per_c", "bias_supply_coeff_dps_per_v")
FIRST_ORDER_SCALE = ("scale", "scale_temp_coeff_per_c", "scale_supply_coeff_per_v")
_FIRST_ORDER_REGISTERS = frozenset(asdict(CalibrationRegisters())) - set(REGISTER_OF.values())


def higher_order_names(order: int) -> list[str]:
    """Record names of the terms beyond first order that an order-`order` fit gives."""
    return [n for k in range(2, order + 1) for n in (HIGHER_BIAS_NAMES[k], HIGHER_SCALE_NAMES[k])]


def declared_beyond_first_order(order: int) -> list[Declared]:
    """The fit step's extra measurements at `order` (informational unless the product has
    limits for them)."""
    return [
        Declared(name, UNITS[name], f"temperature coefficient of order {name[-1]}",
                 informational=True)
        for name in higher_order_names(order)
    ]


@dataclass(frozen=True)
class HigherOrderFit:
    """What `part.fit` holds after an order-2 or -3 fit (read by the program step)."""

    coefficients: FirstOrderCoefficients  # the order-N values of the first-order terms
    bias_fit: TemperatureFit
    scale_fit: TemperatureFit
    registers_beyond_first_order: dict[str, float] = field(default_factory=dict)


def readback_dict(read: CalibrationRegisters) -> dict[str, float]:
    """The registers read back, for the record: the higher-order ones only when not 0 (a
    first-order run's record is as it was)."""
    return {
        k: float(v) for k, v in asdict(read).items() if k in _FIRST_ORDER_REGISTERS or v != 0.0
    }


def _points(part: PartRun, by_kind: dict[str, list[ConditionMeasurement]]) -> list[dict[str, Any]]:
    return [
        {
            "condition": r.name,
            "bias_temp_c": b.temp_c,
            "scale_temp_c": sc.temp_c,
            "supply_v": b.supply_v,
            "bias_dps": b.bias_dps,
            "u_bias_dps": b.u_bias_dps,
            "scale": sc.scale,
            "u_scale": sc.u_scale,
        }
        for r, b, sc in zip(part.conditions.values(), by_kind["bias"], by_kind["scale"],
                            strict=True)
    ]


def record_first_order_summary(
    part: PartRun, by_kind: dict[str, list[ConditionMeasurement]], t0: float, v0: float
) -> None:
    """analysis.temperature_fit for a first-order fit over three or more temperatures (the
    certificate's plot); nothing for today's two-temperature runs."""
    if len({r.temperature_c for r in part.conditions.values()}) < 3:  # chamber setpoints
        return
    try:
        fit_b = fit_temperature(by_kind["bias"], 1, t0, v0)
        fit_s = fit_temperature(by_kind["scale"], 1, t0, v0)
    except AnalysisError:
        return  # the first-order fit itself succeeded; the plot is not worth an error
    part.record.analysis.temperature_fit = TemperatureFitResults.model_validate(
        record_summary(fit_b, fit_s, _points(part, by_kind)))


def fit_beyond_first_order(
    ctx: RunContext, part: PartRun, order: int, by_kind: dict[str, list[ConditionMeasurement]],
    t0: float, v0: float, source: str,
) -> None:
    """Fit to `order` (2 or 3), fill part.fit, the record's calibration, analysis and
    measurements; drops the part ERROR when the conditions cannot carry the order."""
    try:
        fit_b = fit_temperature(by_kind["bias"], order, t0, v0)
        fit_s = fit_temperature(by_kind["scale"], order, t0, v0)
    except AnalysisError as exc:
        ctx.parts.drop(part, Verdict.ERROR, f"order-{order} temperature fit: {exc}")
        return
    b = {n: fit_b.value(n) for n in FIRST_ORDER_BIAS}
    s = {n: fit_s.value(n) for n in FIRST_ORDER_SCALE}
    coefficients = FirstOrderCoefficients(**b, **s, reference_temperature_c=t0,
                                          reference_supply_v=v0)
    higher = higher_order_names(order)
    part.fit = HigherOrderFit(
        coefficients, fit_b, fit_s,
        {REGISTER_OF[n]: (fit_b if n.startswith("bias") else fit_s).value(n) for n in higher},
    )
    cal_b, cal_s = fit_b.as_calibration_dict(), fit_s.as_calibration_dict()
    cal = {k: v for k, v in cal_b.items() if not k.startswith("scale")}
    cal.update({k: v for k, v in cal_s.items() if k.startswith("scale")})
    part.record.conditions = [condition_record(r) for r in part.conditions.values()]
    part.record.calibration = Calibration.model_validate(cal)
    points = _points(part, by_kind)
    part.record.analysis.fit = FitResults.model_validate({
        "source": source,
        "order": order,
        "conditions": [{"name": p["condition"], **{k: v for k, v in p.items()
                                                   if k != "condition"}} for p in points],
    })
    part.record.analysis.temperature_fit = TemperatureFitResults.model_validate(
        record_summary(fit_b, fit_s, points))
    for name in (*FIRST_ORDER_BIAS[1:], *FIRST_ORDER_SCALE[1:], *higher):
        fit = fit_b if name.startswith("bias") else fit_s
        ctx.records.measure(
            part,
            name,
            fit.value(name),
            units=UNITS[name],
            uncertainty_k2=2.0 * fit.uncertainty(name),
            description=f"order-{order} temperature fit coefficient",
        )
