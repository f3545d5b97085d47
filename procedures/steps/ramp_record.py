"""The ramp step's plateaus per part, their fit (procedures/analysis/ramp_fit.py) and what it
leaves: the part's calibration, its `analysis.ramp` and `analysis.fit`, the coefficients'
measurements, and `PartRun.fit` for the `program` step."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from procedures.analysis.bias import window_mean
from procedures.analysis.errors import AnalysisError
from procedures.analysis.hysteresis import OwnHysteresis
from procedures.analysis.ramp_fit import (
    RampFit,
    RampLagTooLarge,
    RampPlateaus,
    TemperatureTrack,
    fit_ramp,
    law_uncertainties,
)
from procedures.analysis.ramp_fit import RampSettings as FitSettings
from procedures.analysis.ramp_linearity import ramp_linearity
from procedures.analysis.temp_supply_fit import COEFFICIENT_NAMES, FirstOrderCoefficients
from procedures.runtime.conditions import plan_conditions
from procedures.runtime.record import Calibration, Verdict
from procedures.runtime.results import FitCondition, FitResults, RampResults
from procedures.runtime.run_context import RunContext
from procedures.runtime.run_parts import PartRun
from procedures.steps.base import check_window, sample_rate_hz, samples_between
from procedures.steps.fit import COEFF_UNITS, record_own_hysteresis
from procedures.steps.registry import Declared
from procedures.steps.sweep import Plateau


@dataclass
class PlateauLog:
    """One part's plateaus as they are measured (the die's rate is taken afterwards, from
    the plateaus' temperatures on both sides)."""

    rows: list[tuple[float, float, float, float, float, float, float, bool]] = field(
        default_factory=list)  # t, ref, u_ref, out, u_out, temp, supply, heating
    dwell_s: float = 6.0
    track: list[tuple[float, float]] = field(default_factory=list)  # the sensor, 1 s means
    commanded: list[float] = field(default_factory=list)  # each row's commanded rate

    def add(self, ctx: RunContext, part: PartRun, *, p: Plateau, supply_v: float,
            heating: bool, dwell_s: float) -> None:
        data = samples_between(ctx, part, p.t0_s, p.t1_s)
        what = f"ramp plateau {p.rate_cmd_dps:g} deg/s"
        if not check_window(ctx, part, data, what, dwell_s):
            return
        wm = window_mean(data["rate_dps"], sample_rate_hz(ctx), part.noise)
        t0, t1 = float(data["time_s"][0]), float(data["time_s"][-1])
        ctx.records.segment(part, "ramp_plateau", len(self.rows), t0, t1,
                            ref_rate_dps=p.ref_dps, ref_angle_deg=p.angle_deg,
                            supply_v=supply_v)
        self.dwell_s = dwell_s
        self._track(data["time_s"], data["temp_c"])
        self.rows.append((0.5 * (t0 + t1), p.ref_dps, p.u_ref_dps, wm.mean_dps,
                          wm.u_mean_dps, float(np.mean(data["temp_c"])), supply_v, heating))
        self.commanded.append(p.rate_cmd_dps)

    def _track(self, time_s: Any, temp_c: Any) -> None:
        t = np.asarray(time_s, dtype=np.float64)
        bins = np.floor(t - t[0]).astype(np.int64)
        counts = np.bincount(bins)
        keep = counts > 0
        times = np.bincount(bins, weights=t)[keep] / counts[keep]
        temps = np.bincount(bins, weights=np.asarray(temp_c, dtype=np.float64))[keep]
        self.track.extend(zip(times.tolist(), (temps / counts[keep]).tolist(), strict=True))

    def temperature_track(self) -> TemperatureTrack:
        arr = np.array(self.track, dtype=np.float64)
        return TemperatureTrack(time_s=arr[:, 0], temp_c=arr[:, 1])

    def plateaus(self) -> RampPlateaus:
        if len(self.rows) < 3:
            raise AnalysisError(f"only {len(self.rows)} ramp plateaus were measured")
        cols = np.array([r[:7] for r in self.rows], dtype=np.float64)
        t, temp = cols[:, 0], cols[:, 5]
        return RampPlateaus.of(time_s=t, ref_dps=cols[:, 1], u_ref_dps=cols[:, 2],
                               out_dps=cols[:, 3], u_out_dps=cols[:, 4], temp_c=temp,
                               tdot_c_per_s=np.gradient(temp, t), supply_v=cols[:, 6])


@dataclass(frozen=True)
class RampProgrammable:
    """What `program` writes (procedures.runtime.run_parts.ProgrammableFit)."""

    coefficients: FirstOrderCoefficients
    registers_beyond_first_order: dict[str, float] = field(default_factory=dict)


def fit_and_record(ctx: RunContext, part: PartRun, *, log: PlateauLog, results: RampResults,
                   bounds: tuple[float, float, float, float], own_bi_dps: float = 0.0
                   ) -> RampFit | None:
    """Fit one part's ramp and record it; a part whose lag the ramp cannot correct leaves
    the run FAIL, one the fit cannot use ERROR, each with the reason (None: no fit).

    The bias wander the plateaus share is the part's own bias instability where the static
    dwell resolved it (`own_bi_dps`), the product's typical as a floor, as the bias step's
    noise model is floored (procedures/steps/stop.py `stop_noise_model`): with the typical
    alone, the parts that wander most had b0's U short (on the simulated bench three of the
    four b0 outside U over 48 parts were drawn at 19-24 deg/h, typical 15)."""
    limit, tau_bound, width, tau_prior = bounds
    t0, v0 = ctx.product.reference_temperature_c, ctx.product.reference_supply_v
    bi_dps = max(ctx.product.bias_instability_deg_per_h / 3600.0, own_bi_dps)
    try:
        plateaus = log.plateaus()
        _plateaus_into(results, plateaus, log)
        fit = fit_ramp(plateaus, FitSettings(
            t0, v0, width, limit, tau_bound,
            bias_instability_dps=bi_dps,
            rrw_dps_per_sqrt_s=ctx.product.rate_random_walk_deg_per_h_per_sqrt_h / 3600.0 / 60.0,
            plateau_s=log.dwell_s, tau_prior_s=tau_prior), log.temperature_track())
    except RampLagTooLarge as exc:
        part.record.analysis.ramp = results.model_copy(update={"refused": str(exc)})
        ctx.parts.drop(part, Verdict.FAIL, f"ramp calibration: {exc}")
        return None
    except AnalysisError as exc:
        part.record.analysis.ramp = results
        ctx.parts.drop(part, Verdict.ERROR, f"ramp calibration: {exc}")
        return None
    part.fit = RampProgrammable(fit.coefficients)
    part.record.calibration = _calibration(fit)
    part.record.analysis.ramp = _with_fit(results, fit)
    part.record.analysis.fit = _corners(ctx, fit)
    _own_hysteresis(ctx, part, fit)
    for name, units in COEFF_UNITS.items():
        ctx.records.measure(part, name, getattr(fit.coefficients, name), units=units,
                            uncertainty_k2=fit.uncertainty_k2(name),
                            description="first-order coefficient (ramp)")
    record_raw(ctx, part, fit)
    record_linearity(ctx, part, plateaus, log.commanded, fit)
    return fit


def _own_hysteresis(ctx: RunContext, part: PartRun, fit: RampFit) -> None:
    """The part's own hysteresis (the ramp's play regressor) against the product's declared
    spread, as the `fit` step records it: beyond it, a WARNING and
    analysis.fit.hysteresis.beyond_typical (the coefficients hold; the part's bias in use
    will move by +-h/2 between heating and cooling)."""
    typ = ctx.product.thermal_typical
    h, u = fit.hysteresis_dps, fit.u_hysteresis_dps
    if typ is None or not (math.isfinite(h) and math.isfinite(u)):
        return
    own = OwnHysteresis.against(h, u, (typ.hysteresis_dps, typ.hysteresis_sigma_dps))
    record_own_hysteresis(ctx, part, own)


def _num(x: float) -> float | None:
    return None if not math.isfinite(x) else float(x)


def _plateaus_into(results: RampResults, p: RampPlateaus, log: PlateauLog) -> None:
    results.time_s = [float(x) for x in p.time_s]
    results.rate_in_dps = [float(x) for x in p.ref_dps]
    results.rate_out_dps = [float(x) for x in p.out_dps]
    results.u_rate_out_dps = [float(x) for x in p.u_out_dps]
    results.die_temp_c = [float(x) for x in p.temp_c]
    results.die_rate_c_per_min = [float(x) * 60.0 for x in p.tdot_c_per_s]
    results.supply_v = [float(x) for x in p.supply_v]
    results.heating = [r[7] for r in log.rows]
    results.die_min_c, results.die_max_c = float(p.temp_c.min()), float(p.temp_c.max())
    results.duration_s = float(p.time_s[-1] - p.time_s[0])


def _with_fit(results: RampResults, fit: RampFit) -> RampResults:
    """The fit's findings into the section (a value the fit could not give is left out)."""
    return _set(results, dict(
        element_tau_s=_num(fit.tau_s),
        u_element_tau_s=_num(fit.u_tau_s),
        tau_bound_s=fit.tau_bound_s,
        gradient_dps_per_c_per_min=fit.gradient_dps_per_c_per_min,
        hysteresis_dps=fit.hysteresis_dps,
        u_hysteresis_dps=fit.u_hysteresis_dps,
        chi2_per_dof=fit.chi2_per_dof,
        lag_error_k2=dict(fit.lag_error),
        residual_dps=[float(x) for x in fit.residual_dps],
    ))


def _set(results: RampResults, values: dict[str, Any]) -> RampResults:
    """`results` with `values` set, those that are None left out of the record."""
    return results.model_copy(update={k: v for k, v in values.items() if v is not None})


def _calibration(fit: RampFit) -> Calibration:
    co = fit.coefficients
    cal: dict[str, Any] = {
        name: {"value": float(getattr(co, name)), "uncertainty_k2": fit.uncertainty_k2(name)}
        for name in COEFFICIENT_NAMES
    }
    cal["reference_temperature_c"] = co.reference_temperature_c
    cal["reference_supply_v"] = co.reference_supply_v
    return Calibration.model_validate(cal)


def _corners(ctx: RunContext, fit: RampFit) -> FitResults:
    """analysis.fit: the fitted laws at the span's corners (what the certificate and the
    accuracy benchmark read per condition), with their k=1 uncertainties."""
    co = fit.coefficients
    rows = []
    for temp in sorted(set(ctx.procedure.conditions.temperatures_c)):
        for volts in ctx.procedure.conditions.supplies_v:
            u_bias, u_scale = law_uncertainties(fit, temp, volts)
            rows.append(FitCondition(
                name=f"ramp@T{temp:g}_V{volts:g}", bias_temp_c=temp, scale_temp_c=temp,
                supply_v=volts, bias_dps=float(co.bias_at(temp, volts)),
                u_bias_dps=u_bias, scale=float(co.scale_at(temp, volts)), u_scale=u_scale))
    return FitResults(source="ramp", conditions=rows)


RAW = (
    Declared("raw_bias_dps", "deg/s", "uncalibrated bias at each condition (the ramp's "
             "fitted law)", per_condition=True),
    Declared("raw_scale_error", "1", "uncalibrated scale / nominal - 1 at each condition "
             "(the ramp's fitted law)", per_condition=True),
    Declared("nonlinearity_pct_fs", "% FS", "largest residual from the line (the ramp's "
             "rates at the reference point)"),
    Declared("asymmetry", "1", "(K+ - K-) / mean K (the ramp's rates at the reference "
             "point)"),
)


def record_raw(ctx: RunContext, part: PartRun, fit: RampFit) -> None:
    """raw_bias_dps and raw_scale_error at each of the procedure's conditions, as the
    eol-rate-table's bias and rate_table steps set them there: here from the fitted laws,
    with their uncertainties (law_uncertainties, k=1, doubled)."""
    co, nominal = fit.coefficients, ctx.product.nominal_scale
    for cond in plan_conditions(list(ctx.procedure.conditions.temperatures_c),
                                list(ctx.procedure.conditions.supplies_v)):
        temp, volts = cond.temperature_c, cond.supply_v
        u_bias, u_scale = law_uncertainties(fit, temp, volts)
        ctx.records.measure(part, "raw_bias_dps", float(co.bias_at(temp, volts)),
                            units="deg/s", uncertainty_k2=2 * u_bias, condition=cond.name,
                            description=RAW[0].description)
        ctx.records.measure(part, "raw_scale_error",
                            float(co.scale_at(temp, volts)) / nominal - 1.0, units="1",
                            uncertainty_k2=2 * u_scale / nominal, condition=cond.name,
                            description=RAW[1].description)


def record_linearity(ctx: RunContext, part: PartRun, plateaus: RampPlateaus,
                     commanded: list[float], fit: RampFit) -> None:
    """nonlinearity_pct_fs and asymmetry from the ramp's rates carried to the reference
    point (procedures/analysis/ramp_linearity.py), as rate_table.py defines them; the line
    fit into analysis.ramp.linearity."""
    try:
        lin = ramp_linearity(plateaus, commanded, fit, ctx.product.range_dps)
    except AnalysisError as exc:
        ctx.parts.drop(part, Verdict.ERROR, f"ramp linearity: {exc}")
        return
    ctx.records.measure(part, "nonlinearity_pct_fs", lin.nonlinearity_pct_fs, units="% FS",
                        uncertainty_k2=2 * lin.u_nonlinearity_pct_fs,
                        description=RAW[2].description)
    ctx.records.measure(part, "asymmetry", lin.asymmetry_ppm * 1e-6, units="1",
                        uncertainty_k2=2 * lin.u_asymmetry_ppm * 1e-6,
                        description=RAW[3].description)
    ramp = part.record.analysis.ramp
    if ramp is not None:
        part.record.analysis.ramp = _set(ramp, dict(
            nonlinearity_pct_fs=lin.nonlinearity_pct_fs, asymmetry_ppm=lin.asymmetry_ppm,
            linearity_rate_in_dps=list(lin.input_rate_dps),
            linearity_residual_dps=list(lin.residual_dps)))
