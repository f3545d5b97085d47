"""Verification after programming: the part's own compensated output against the encoder."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from procedures.analysis.bias import window_mean
from procedures.analysis.errors import AnalysisError
from procedures.analysis.verification import verify_correction
from procedures.engine import PartRun, RunContext
from procedures.record import Verdict
from procedures.steps.base import BaseStep, check_window, sample_rate_hz, samples_between
from procedures.steps.sweep import Plateau, run_plateaus


@dataclass
class Verify(BaseStep):
    name: str = "verify"
    policy: str = "verify"

    def estimate_s(self, ctx: RunContext) -> float:
        cfg = ctx.procedure.verify
        assert cfg is not None
        return (len(cfg.rates_dps) + 1) * (cfg.dwell_s + cfg.settle_s + 1.0) + 5.0

    def main(self, ctx: RunContext) -> None:
        cfg = ctx.procedure.verify
        table = ctx.bench.table
        assert cfg is not None and table is not None
        supply_v = cfg.supply_v if cfg.supply_v is not None else ctx.product.reference_supply_v
        ctx.set_supply_voltage(supply_v)
        self.supply_v = supply_v
        table.enable()
        ctx.sleep(cfg.settle_s)
        t0 = ctx.clock.now_s()
        ctx.sleep(cfg.dwell_s)
        rest = (t0, ctx.clock.now_s())
        plateaus = run_plateaus(
            ctx,
            list(cfg.rates_dps),
            cfg.dwell_s,
            cfg.settle_s,
            ctx.procedure.rate_table.accel_dps2 if ctx.procedure.rate_table else 100.0,
            60.0,
        )
        ctx.each(lambda part: self._analyse(ctx, part, rest, plateaus))

    def _analyse(
        self, ctx: RunContext, part: PartRun, rest: tuple[float, float], plateaus: list[Plateau]
    ) -> None:
        cfg = ctx.procedure.verify
        assert cfg is not None
        fs = sample_rate_hz(ctx)
        noise = part.extra.get("noise")
        data = samples_between(ctx, part, *rest)
        if not check_window(ctx, part, data, "verification at rest", cfg.dwell_s):
            return
        zero = window_mean(data["rate_dps"], fs, noise)
        ctx.measure(
            part,
            "residual_bias_dps",
            zero.mean_dps,
            units="deg/s",
            uncertainty_k2=2 * zero.u_mean_dps,
            condition="verify",
            description="compensated output at rest",
        )
        ctx.segment(
            part,
            "verify",
            0,
            float(data["time_s"][0]),
            float(data["time_s"][-1]),
            ref_rate_dps=0.0,
            supply_v=self.supply_v,
        )
        ref, u_ref, out, u_out = [], [], [], []
        for i, p in enumerate(plateaus):
            d = samples_between(ctx, part, p.t0_s, p.t1_s)
            if not check_window(
                ctx, part, d, f"verification at {p.rate_cmd_dps:g} deg/s", cfg.dwell_s
            ):
                return
            wm = window_mean(d["rate_dps"], fs, noise)
            ref.append(p.ref_dps)
            u_ref.append(p.u_ref_dps)
            out.append(wm.mean_dps)
            u_out.append(wm.u_mean_dps)
            ctx.segment(
                part,
                "verify",
                i + 1,
                float(d["time_s"][0]),
                float(d["time_s"][-1]),
                ref_rate_dps=p.ref_dps,
                ref_angle_deg=p.angle_deg,
                supply_v=self.supply_v,
            )
        try:
            # the rest offset is the residual bias; the scale residual is judged without it
            result = verify_correction(
                ref, u_ref, np.asarray(out) - zero.mean_dps, u_out, ctx.product.range_dps
            )
        except AnalysisError as exc:
            ctx.drop(part, Verdict.ERROR, f"verification: {exc}")
            return
        residuals = []
        for pt in result.points:
            rel = pt.error_dps / pt.reference_rate_dps
            u_rel = pt.u_error_dps / abs(pt.reference_rate_dps)
            ctx.measure(
                part,
                "residual_scale_error",
                rel,
                units="1",
                uncertainty_k2=2 * u_rel,
                condition=f"verify@{pt.reference_rate_dps:.0f}dps",
                description="compensated output / encoder rate - 1",
            )
            residuals.append(
                {
                    "condition": f"verify@{pt.reference_rate_dps:.0f}dps",
                    "rate_in_dps": pt.reference_rate_dps,
                    "error_dps": pt.error_dps,
                    "error_pct": 100 * rel,
                    "u_error_pct_k2": 200 * u_rel,
                }
            )
        part.record.verification = {
            "residuals": residuals,
            "residual_bias_dps": zero.mean_dps,
            "max_error_pct": max(abs(float(r["error_pct"])) for r in residuals),  # type: ignore[arg-type]
            "max_abs_error_pct_fs": result.max_abs_error_pct_fs,
            "supply_v": self.supply_v,
            "die_temperature_c": float(np.mean(data["temp_c"])),
        }
