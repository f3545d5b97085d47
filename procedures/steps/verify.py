"""Verification after programming: the part's own compensated output against the encoder."""

from __future__ import annotations

from typing import Any

import numpy as np
from pydantic import Field

from common.bounded import MAX_ACCEL_DPS2, MAX_LIST, ONE_HOUR_S
from procedures.analysis.bias import window_mean
from procedures.analysis.errors import AnalysisError
from procedures.analysis.verification import VerificationResult, verify_correction
from procedures.runtime.record import Verdict
from procedures.runtime.results import Verification, VerificationRow
from procedures.runtime.run_context import RunContext
from procedures.runtime.run_parts import PartRun
from procedures.steps.base import check_window, sample_rate_hz, samples_between
from procedures.steps.registry import Declared, Provided, StepSettings, StepType
from procedures.steps.sweep import Plateau, run_plateaus
from procedures.units import Rate, Seconds, Volts


class VerifySettings(StepSettings):
    rates_dps: list[Rate] = Field(
        min_length=1, max_length=MAX_LIST, description="verification rates, deg/s"
    )
    dwell_s: Seconds = Field(10.0, gt=0, description="averaging time at each rate")
    settle_s: float = Field(1.0, ge=0, le=ONE_HOUR_S, description="wait after at-rate")
    supply_v: Volts | None = Field(None, description="supply during verification (default V0)")
    accel_dps2: float = Field(
        100.0, gt=0, le=MAX_ACCEL_DPS2, description="table acceleration, deg/s^2"
    )
    at_rate_timeout_s: Seconds = Field(60.0, gt=0, description="time allowed to reach a rate")


class Verify(StepType[VerifySettings]):
    """After programming: the part's own compensated output against the table's encoder."""

    type_name = "verify"
    Settings = VerifySettings
    uses_table = True
    Results = Verification

    @classmethod
    def requires(cls, settings: Any) -> set[Provided]:
        return {Provided.PROGRAMMED}

    @classmethod
    def measurements(cls, settings: Any) -> list[Declared]:
        return [
            Declared("residual_bias_dps", "deg/s", "compensated output at rest"),
            Declared("residual_scale_error", "1", "compensated output / encoder rate - 1"),
        ]

    def estimate_s(self, ctx: RunContext) -> float:
        cfg = self.settings
        return (len(cfg.rates_dps) + 1) * (cfg.dwell_s + cfg.settle_s + 1.0) + 5.0

    def main(self, ctx: RunContext) -> None:
        cfg = self.settings
        table = ctx.instruments.need_table()
        supply_v = cfg.supply_v if cfg.supply_v is not None else ctx.product.reference_supply_v
        ctx.instruments.set_supply_voltage(supply_v)
        self.supply_v = supply_v
        table.enable()
        ctx.wait.sleep(cfg.settle_s)
        t0 = ctx.wait.clock.now_s()
        ctx.wait.sleep(cfg.dwell_s)
        rest = (t0, ctx.wait.clock.now_s())
        plateaus = run_plateaus(
            ctx,
            list(cfg.rates_dps),
            cfg.dwell_s,
            cfg.settle_s,
            cfg.accel_dps2,
            cfg.at_rate_timeout_s,
        )
        ctx.parts.each(lambda part: self._analyse(ctx, part, rest, plateaus))

    def _analyse(
        self, ctx: RunContext, part: PartRun, rest: tuple[float, float], plateaus: list[Plateau]
    ) -> None:
        cfg = self.settings
        fs = sample_rate_hz(ctx)
        data = samples_between(ctx, part, *rest)
        if not check_window(ctx, part, data, "verification at rest", cfg.dwell_s):
            return
        zero = window_mean(data["rate_dps"], fs, part.noise)
        ctx.records.measure(
            part,
            "residual_bias_dps",
            zero.mean_dps,
            units="deg/s",
            uncertainty_k2=2 * zero.u_mean_dps,
            condition="verify",
            description="compensated output at rest",
        )
        ctx.records.segment(
            part,
            "verify",
            0,
            float(data["time_s"][0]),
            float(data["time_s"][-1]),
            ref_rate_dps=0.0,
            supply_v=self.supply_v,
        )
        means = self._plateau_means(ctx, part, plateaus)
        if means is None:
            return
        ref, u_ref, out, u_out = means
        try:
            # the rest offset is the residual bias; the scale residual is judged without it
            result = verify_correction(
                ref, u_ref, np.asarray(out) - zero.mean_dps, u_out, ctx.product.range_dps
            )
        except AnalysisError as exc:
            ctx.parts.drop(part, Verdict.ERROR, f"verification: {exc}")
            return
        residuals = self._residuals(ctx, part, result)
        part.record.verification = Verification(
            residuals=residuals,
            residual_bias_dps=zero.mean_dps,
            max_error_pct=max(abs(r.error_pct or 0.0) for r in residuals),
            max_abs_error_pct_fs=result.max_abs_error_pct_fs,
            supply_v=self.supply_v,
            die_temperature_c=float(np.mean(data["temp_c"])),
        )

    def _plateau_means(
        self, ctx: RunContext, part: PartRun, plateaus: list[Plateau]
    ) -> tuple[list[float], list[float], list[float], list[float]] | None:
        """Reference rates, their u, the part's mean outputs and their u (k=1), one per
        plateau; None when a window was not usable (the part is then dropped)."""
        cfg = self.settings
        fs = sample_rate_hz(ctx)
        ref: list[float] = []
        u_ref: list[float] = []
        out: list[float] = []
        u_out: list[float] = []
        for i, p in enumerate(plateaus):
            d = samples_between(ctx, part, p.t0_s, p.t1_s)
            if not check_window(
                ctx, part, d, f"verification at {p.rate_cmd_dps:g} deg/s", cfg.dwell_s
            ):
                return None
            wm = window_mean(d["rate_dps"], fs, part.noise)
            ref.append(p.ref_dps)
            u_ref.append(p.u_ref_dps)
            out.append(wm.mean_dps)
            u_out.append(wm.u_mean_dps)
            ctx.records.segment(
                part,
                "verify",
                i + 1,
                float(d["time_s"][0]),
                float(d["time_s"][-1]),
                ref_rate_dps=p.ref_dps,
                ref_angle_deg=p.angle_deg,
                supply_v=self.supply_v,
            )
        return ref, u_ref, out, u_out

    def _residuals(
        self, ctx: RunContext, part: PartRun, result: VerificationResult
    ) -> list[VerificationRow]:
        """residual_scale_error at each verification rate, measured and as record rows."""
        residuals = []
        for pt in result.points:
            rel = pt.error_dps / pt.reference_rate_dps
            u_rel = pt.u_error_dps / abs(pt.reference_rate_dps)
            ctx.records.measure(
                part,
                "residual_scale_error",
                rel,
                units="1",
                uncertainty_k2=2 * u_rel,
                condition=f"verify@{pt.reference_rate_dps:.0f}dps",
                description="compensated output / encoder rate - 1",
            )
            residuals.append(
                VerificationRow(
                    condition=f"verify@{pt.reference_rate_dps:.0f}dps",
                    rate_in_dps=pt.reference_rate_dps,
                    error_dps=pt.error_dps,
                    error_pct=100 * rel,
                    u_error_pct_k2=200 * u_rel,
                )
            )
        return residuals
