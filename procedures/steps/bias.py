"""Bias at rest (and, at the first condition, the Allan deviation of the part's noise)."""

from __future__ import annotations

import math
from typing import Any, Literal

import numpy as np
from pydantic import Field, field_validator

from procedures.analysis.allan import AllanAnalysis, analyze_allan
from procedures.analysis.bias import estimate_bias, required_averaging_time_s
from procedures.analysis.bias_wander import window_mean_covariance
from procedures.analysis.errors import AnalysisError
from procedures.runtime.record import Verdict
from procedures.runtime.results import AllanResults
from procedures.runtime.run_context import RunContext
from procedures.runtime.run_parts import PartRun
from procedures.steps.base import check_window, sample_rate_hz, samples_between
from procedures.steps.registry import Declared, Provided, StepSettings, StepType
from procedures.units import Seconds


class BiasSettings(StepSettings):
    dwell_s: Seconds | Literal["auto"] = Field(
        30.0, description="static averaging time, s, or 'auto' (from Allan deviation and target)"
    )
    target_accuracy_dps: float = Field(0.005, gt=0, le=100, description="k=2 target for 'auto'")
    min_dwell_s: Seconds = Field(10.0, gt=0, description="pilot dwell for 'auto'")
    max_dwell_s: Seconds = Field(300.0, gt=0, description="cap for 'auto'")
    wander_factor: float | None = Field(
        None,
        ge=0,
        le=100,
        description="bias wander between conditions added to each condition's bias "
        "uncertainty: none = the wander of the window's mean under the bias instability "
        "(its Gauss-Markov model, about 1.2 x for a 30 s window); a number = that many times "
        "the bias instability (0: white noise only)",
    )
    allan: Literal["first_condition", "every_condition", "never"] = Field(
        "first_condition",
        description="where the Allan deviation (noise_arw_deg_per_sqrt_h, "
        "bias_instability_deg_per_h) is measured: at the loop's first condition, at every one, "
        "or never",
    )

    @field_validator("dwell_s")
    @classmethod
    def _positive(cls, value: float | str) -> float | str:
        if not isinstance(value, str) and value <= 0:
            raise ValueError("dwell must be a positive number of seconds or 'auto'")
        return value


NOISE = (
    Declared("noise_arw_deg_per_sqrt_h", "deg/sqrt(h)", "angle random walk from the Allan "
             "deviation"),
    Declared("bias_instability_deg_per_h", "deg/h", "bias instability (short record: "
             "indicative)"),
)


def _hysteresis_state(part: PartRun) -> float | None:
    """The part's hysteresis state now (its stream follows it from power-on; None when the
    product declares no hysteresis), read under the stream's lock."""
    stream = part.stream
    if stream is None or stream.hysteresis is None:
        return None
    with stream.lock:
        return stream.hysteresis.state


class Bias(StepType[BiasSettings]):
    """Bias at rest (inside for_each: condition); the Allan deviation where `allan` says."""

    type_name = "bias"
    Settings = BiasSettings
    provides = frozenset({Provided.BIAS})
    Results = AllanResults

    @classmethod
    def measurements(cls, settings: Any) -> list[Declared]:
        raw = Declared("raw_bias_dps", "deg/s", "uncalibrated bias at rest", per_condition=True)
        return [raw, *(NOISE if settings.allan != "never" else ())]

    @property
    def first(self) -> bool:
        """Is the Allan deviation measured here?"""
        allan = self.settings.allan
        return allan == "every_condition" or (
            allan == "first_condition" and self.place.condition_index == 0
        )

    def expected(self) -> list[Declared]:
        return [d for d in super().expected() if self.first or d not in NOISE]

    def estimate_s(self, ctx: RunContext) -> float:
        cfg = self.settings
        return (
            float(cfg.dwell_s)
            if cfg.dwell_s != "auto"
            else 0.5 * (cfg.min_dwell_s + cfg.max_dwell_s)
        )

    def main(self, ctx: RunContext) -> None:
        cfg = self.settings
        fs = sample_rate_hz(ctx)
        if ctx.instruments.table is not None:
            ctx.instruments.snapshot()
        t0 = ctx.wait.clock.now_s()
        if cfg.dwell_s == "auto":
            ctx.wait.sleep(cfg.min_dwell_s)
            need = cfg.min_dwell_s
            for part in ctx.parts.alive():
                data = samples_between(ctx, part, t0, ctx.wait.clock.now_s())
                try:
                    noise = analyze_allan(data["rate_dps"], fs).noise.model
                    need = max(need, required_averaging_time_s(noise, cfg.target_accuracy_dps))
                except AnalysisError:
                    need = cfg.max_dwell_s
            dwell = min(max(need, cfg.min_dwell_s), cfg.max_dwell_s)
            ctx.records.event(
                f"bias: automatic dwell {dwell:.1f} s for {cfg.target_accuracy_dps:g} deg/s (k=2)"
            )
            ctx.wait.sleep(t0 + dwell - ctx.wait.clock.now_s())
        else:
            dwell = float(cfg.dwell_s)
            ctx.wait.sleep(dwell)
        t1 = ctx.wait.clock.now_s()
        if ctx.instruments.table is not None:
            ctx.instruments.snapshot()
        ctx.parts.each(lambda part: self._analyse(ctx, part, t0, t1, dwell))

    def _wander_dps(self, t0: float, t1: float, b_dps: float, rrw: float) -> float:
        """How far this window's mean may lie from the part's bias at this condition: the
        bias wander of a [t0, t1] mean (procedures/analysis/bias_wander.py), or the
        procedure's multiple of the bias instability."""
        factor = self.settings.wander_factor
        if factor is not None:
            return factor * b_dps
        cov = window_mean_covariance(np.array([t0]), np.array([t1]), b_dps, rrw)
        return math.sqrt(float(cov[0, 0]))

    def _analyse(self, ctx: RunContext, part: PartRun, t0: float, t1: float, dwell: float) -> None:
        fs = sample_rate_hz(ctx)
        data = samples_between(ctx, part, t0, t1)
        if not check_window(ctx, part, data, f"bias at {self.condition}", dwell):
            return
        # the noise model from the longest static record at this condition: the stability
        # window (die within its band, table at rest) and the dwell, so that slow terms (bias
        # instability, the die's residual creep) reach the bias uncertainty
        long = samples_between(ctx, part, min(self._static_from(part, t0), t0), t1)
        try:
            allan = analyze_allan(
                long["rate_dps"]
                if long["rate_dps"].size > data["rate_dps"].size
                else data["rate_dps"],
                fs,
            )
            noise = allan.noise.model
            est = estimate_bias(data["rate_dps"], fs, noise)
        except AnalysisError as exc:
            ctx.parts.drop(part, Verdict.ERROR, f"bias at {self.condition}: {exc}")
            return
        res = part.conditions[self.condition]
        # the bias wanders between conditions (bias instability): a short record cannot see
        # it, so the product's typical value is its floor
        b_dps = max(noise.bias_instability_dps, ctx.product.bias_instability_deg_per_h / 3600.0)
        rrw = ctx.product.rate_random_walk_deg_per_h_per_sqrt_h / 216000.0
        # the windows measured after this one (rate plateaus, stops, verification) see the
        # wander within them too: their model has the same floor
        part.noise = noise.with_floor(b_dps, rrw)
        u_wander = self._wander_dps(t0, t1, b_dps, rrw)
        res.bias_dps, res.u_bias_dps = est.bias_dps, math.hypot(est.u_bias_dps, u_wander)
        res.note_temperature("bias", data["temp_c"], data["time_s"])
        res.hysteresis_state = _hysteresis_state(part)
        ctx.records.measure(
            part,
            "raw_bias_dps",
            est.bias_dps,
            units="deg/s",
            uncertainty_k2=2 * res.u_bias_dps,
            condition=self.condition,
            description="uncalibrated bias at rest",
        )
        ctx.records.segment(
            part,
            "static",
            0,
            float(data["time_s"][0]),
            float(data["time_s"][-1]),
            ref_rate_dps=0.0,
            temp_setpoint_c=res.temperature_c,
            supply_v=res.supply_v,
        )
        if self.first:
            self._record_allan(ctx, part, allan, float(data["time_s"][-1] - data["time_s"][0]))

    def _static_from(self, part: PartRun, t0: float) -> float:
        """Where the static record at this condition began: the thermal step's stability
        window, when it judged one (station clock); else t0."""
        stab = part.record.analysis.stability.get(self.condition)
        if stab is None:
            return t0
        start = t0 if stab.stable_at_station_s is None else stab.stable_at_station_s
        return start - (stab.window_s or 0.0)

    def _record_allan(self, ctx: RunContext, part: PartRun, allan: AllanAnalysis,
                      record_s: float) -> None:
        record_allan(ctx, part, allan, record_s, self.condition)


def record_allan(ctx: RunContext, part: PartRun, allan: AllanAnalysis, record_s: float,
                 condition: str) -> None:
    """analysis.allan and the noise measurements (NOISE) from a static record's Allan
    deviation (this step's, or the ramp's static dwell)."""
    noise = allan.noise.model
    arw = noise.arw_deg_per_sqrt_h
    bi = noise.bias_instability_deg_per_h
    part.record.analysis.allan = AllanResults(
        condition=condition,
        tau_s=[float(x) for x in allan.adev.tau_s],
        adev_dps=[float(x) for x in allan.adev.adev_dps],
        arw_deg_per_sqrt_h=arw,
        bias_instability_deg_per_h=bi,
        rate_random_walk_deg_per_h_per_sqrt_h=noise.rrw_deg_per_h_per_sqrt_h,
        record_s=record_s,
    )
    ctx.records.measure(
        part,
        "noise_arw_deg_per_sqrt_h",
        arw if math.isfinite(arw) else None,
        units="deg/sqrt(h)",
        condition=condition,
        uncertainty_k2=2 * allan.noise.u_arw_deg_per_sqrt_h,
        description="angle random walk from the Allan deviation",
    )
    if bi > 0 and np.isfinite(bi):
        ctx.records.measure(
            part,
            "bias_instability_deg_per_h",
            bi,
            units="deg/h",
            condition=condition,
            uncertainty_k2=2 * allan.noise.u_bias_instability_deg_per_h,
            description="bias instability (short record: indicative)",
        )
