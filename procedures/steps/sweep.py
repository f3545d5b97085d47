"""Rate-table sweep: plateaus at the rate set, reference rate from the encoder."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from pydantic import Field

from common.bounded import MAX_ACCEL_DPS2, MAX_LIST, MAX_REPEATS, ONE_HOUR_S
from procedures.analysis.bias import window_mean
from procedures.analysis.errors import AnalysisError
from procedures.analysis.rate_table import fit_rate_table, reference_rate_from_encoder
from procedures.runtime.record import Verdict
from procedures.runtime.results import RateTableResults
from procedures.runtime.run_context import RunContext
from procedures.runtime.run_parts import PartRun
from procedures.steps.base import check_window, sample_rate_hz, samples_between
from procedures.steps.registry import Declared, Provided, StepSettings, StepType
from procedures.units import Rate, Seconds

CHANGE_MARGIN_S = 0.1  # polling starts this long before a rate change could be done


def plateau_time_s(rate_dps: float, previous_dps: float, accel_dps2: float) -> float:
    return abs(rate_dps - previous_dps) / accel_dps2


@dataclass
class Plateau:
    rate_cmd_dps: float
    t0_s: float
    t1_s: float
    ref_dps: float
    u_ref_dps: float
    angle_deg: float


def measure_plateau(
    ctx: RunContext, rate: float, dwell_s: float, settle_s: float, accel_dps2: float,
    timeout_s: float, *, sleep_through_change: bool = False,
) -> Plateau:
    """The table to `rate`, settled, then one plateau: its reference rate from two encoder
    snapshots around the dwell. `sleep_through_change`: wait out the rate change the
    acceleration allows before polling the table (a ramp changes rate every few seconds;
    polled at the table's 0.05 s, each change cost some 40 status reads, and in lockstep as
    many advances of every socket's stream)."""
    table = ctx.instruments.need_table()
    ctx.wait.check()
    before_dps = table.read_status().rate_dps if sleep_through_change else rate
    table.set_rate(rate, accel_dps2)
    change_s = abs(rate - before_dps) / accel_dps2 - CHANGE_MARGIN_S
    if change_s > 0:
        ctx.wait.sleep(change_s)
    table.wait_at_rate(timeout_s)
    ctx.wait.sleep(settle_s)
    t0, s0 = ctx.instruments.snapshot()
    ctx.wait.sleep(dwell_s)
    t1, s1 = ctx.instruments.snapshot()
    c0 = s0.encoder_counts_unwrapped or s0.encoder_counts
    c1 = s1.encoder_counts_unwrapped or s1.encoder_counts
    ref = reference_rate_from_encoder(
        [c0, c1],
        [s0.controller_time_s, s1.controller_time_s],
        table.counts_per_rev(),
        time_resolution_s=max(
            s0.controller_time_resolution_s, s1.controller_time_resolution_s
        ),
        counts_modulo=1 << 62 if s0.encoder_counts_unwrapped else 1 << 32,
    )
    return Plateau(rate, t0, t1, ref.rate_dps, ref.u_rate_dps, ref.angle_deg)


def run_plateaus(
    ctx: RunContext,
    rates: list[float],
    dwell_s: float,
    settle_s: float,
    accel_dps2: float,
    timeout_s: float,
) -> list[Plateau]:
    """Drive the table through `rates`; each plateau's reference from two encoder snapshots."""
    table = ctx.instruments.need_table()
    out = [measure_plateau(ctx, rate, dwell_s, settle_s, accel_dps2, timeout_s)
           for rate in rates]
    table.set_rate(0.0, accel_dps2)
    table.wait_at_rate(timeout_s)
    return out


class RateTableSettings(StepSettings):
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


class RateSweep(StepType[RateTableSettings]):
    """Rate-table sweep at one condition: scale, nonlinearity and asymmetry from a line fit."""

    type_name = "rate_table"
    Settings = RateTableSettings
    uses_table = True
    provides = frozenset({Provided.SCALE_TABLE})
    Results = RateTableResults

    @classmethod
    def measurements(cls, settings: Any) -> list[Declared]:
        return [
            Declared("raw_scale_error", "1", "uncalibrated scale / nominal - 1 (rate table)",
                     per_condition=True),
            Declared("nonlinearity_pct_fs", "% FS", "largest residual from the line",
                     per_condition=True),
            Declared("asymmetry", "1", "(K+ - K-) / mean K", per_condition=True),
        ]

    def estimate_s(self, ctx: RunContext) -> float:
        cfg = self.settings
        rates = cfg.rates_dps * cfg.repeats
        ramps = (
            sum(abs(b - a) for a, b in zip([0.0, *rates], [*rates, 0.0], strict=True))
            / cfg.accel_dps2
        )
        return len(rates) * (cfg.plateau_dwell_s + cfg.settle_s + 0.5) + ramps

    def main(self, ctx: RunContext) -> None:
        cfg = self.settings
        ctx.instruments.need_table().enable()
        self.plateaus: list[Plateau] = run_plateaus(
            ctx,
            list(cfg.rates_dps) * cfg.repeats,
            cfg.plateau_dwell_s,
            cfg.settle_s,
            cfg.accel_dps2,
            cfg.at_rate_timeout_s,
        )
        ctx.parts.each(lambda part: self._analyse(ctx, part))

    def _analyse(self, ctx: RunContext, part: PartRun) -> None:
        cfg = self.settings
        fs = sample_rate_hz(ctx)
        noise = part.noise
        res = part.conditions[self.condition]
        ref, u_ref, out, u_out = [], [], [], []
        for i, p in enumerate(self.plateaus):
            data = samples_between(ctx, part, p.t0_s, p.t1_s)
            if not check_window(
                ctx,
                part,
                data,
                f"plateau {p.rate_cmd_dps:g} deg/s at {self.condition}",
                cfg.plateau_dwell_s,
            ):
                return
            wm = window_mean(data["rate_dps"], fs, noise)
            res.note_temperature("scale", data["temp_c"], data["time_s"])
            ref.append(p.ref_dps)
            u_ref.append(p.u_ref_dps)
            out.append(wm.mean_dps)
            u_out.append(wm.u_mean_dps)
            ctx.records.segment(
                part,
                "plateau",
                i,
                float(data["time_s"][0]),
                float(data["time_s"][-1]),
                ref_rate_dps=p.ref_dps,
                ref_angle_deg=p.angle_deg,
                temp_setpoint_c=res.temperature_c,
                supply_v=res.supply_v,
            )
        try:
            fit = fit_rate_table(ref, u_ref, out, u_out, ctx.product.range_dps)
        except AnalysisError as exc:
            ctx.parts.drop(part, Verdict.ERROR, f"rate-table fit at {self.condition}: {exc}")
            return
        res.table_fit = fit
        nominal = ctx.product.nominal_scale
        ctx.records.measure(
            part,
            "raw_scale_error",
            fit.scale / nominal - 1.0,
            units="1",
            uncertainty_k2=2 * fit.u_scale / nominal,
            condition=self.condition,
            description="uncalibrated scale / nominal - 1 (rate table)",
        )
        ctx.records.measure(
            part,
            "nonlinearity_pct_fs",
            fit.nonlinearity_pct_fs,
            units="% FS",
            uncertainty_k2=2 * fit.u_nonlinearity_pct_fs,
            condition=self.condition,
        )
        ctx.records.measure(
            part,
            "asymmetry",
            fit.asymmetry_ppm * 1e-6,
            units="1",
            uncertainty_k2=2 * fit.u_asymmetry_ppm * 1e-6,
            condition=self.condition,
        )
        part.record.analysis.rate_table[self.condition] = RateTableResults(
            rate_in_dps=[float(x) for x in ref],
            u_rate_in_dps=[float(x) for x in u_ref],
            rate_out_dps=[float(x) for x in out],
            u_rate_out_dps=[float(x) for x in u_out],
            residual_dps=[float(x) for x in fit.residual_dps],
            scale=fit.scale,
            u_scale=fit.u_scale,
            bias_dps=fit.bias_dps,
            u_bias_dps=fit.u_bias_dps,
            nonlinearity_pct_fs=fit.nonlinearity_pct_fs,
            asymmetry_ppm=fit.asymmetry_ppm,
        )
