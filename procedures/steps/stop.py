"""The article's stop method: rest, move to the second stop, rest, move back, rest.

The record is analysed by `procedures.analysis.stop_method` (moves found in the data, bias
from the leading rest). The reference angle is the encoder's measured travel (position at
rest after each move minus before it) or the fixture's stored stop angle with its uncertainty.
The analysis gets the part's noise model from the bias step's longer static record, with the
product's typical bias instability as a floor (`stop_noise_model`): the bias drifts between
the leading rest and each move, and a few seconds of rest cannot show by how much.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any, ClassVar, Literal

import numpy as np
from pydantic import BaseModel, Field

from common.bounded import MAX_REPEATS, ONE_HOUR_S
from procedures.analysis.allan import NoiseModel
from procedures.analysis.consistency import stop_vs_rate_table
from procedures.analysis.errors import AnalysisError
from procedures.analysis.rate_table import RateTableFit
from procedures.analysis.stop_method import (
    StopMethodResult,
    StopMethodSettings,
    analyze_stop_method,
)
from procedures.runtime.record import Verdict
from procedures.runtime.results import (
    RemeasuredFirst,
    RemeasuredResults,
    RemeasuredSecond,
    StopMethodResults,
    StopMove,
    Verification,
    VerificationRow,
)
from procedures.runtime.run_context import RunContext
from procedures.runtime.run_parts import ConditionResult, PartRun, StopScale
from procedures.steps.base import check_window, samples_between
from procedures.steps.program import failed_limits
from procedures.steps.registry import Declared, Provided, StepSettings, StepType
from procedures.units import Seconds, Volts

# the table counts as already at the first stop within this (a move is skipped)
AT_STOP_TOLERANCE_DEG = 0.001


def stop_noise_model(ctx: RunContext, part: PartRun) -> NoiseModel | None:
    """The part's noise model for the stop analysis, bias instability floored at the product's.

    Without this the stop scale's uncertainty held white noise only and came out about 20 %
    short on the simulated bench (benchmarks/bench_consistency.py); a minute's record rarely
    resolves the bias instability, so the product's typical value stands in for it.
    """
    noise = part.noise
    if noise is None:
        return None
    floor_dps = ctx.product.bias_instability_deg_per_h / 3600.0
    return replace(noise, bias_instability_dps=max(noise.bias_instability_dps, floor_dps))


def stop_angle(part: PartRun) -> tuple[float, float]:
    """The fixture's stop angle and its k=1 uncertainty (step power read it), deg."""
    if part.stop_angle is None:
        raise AnalysisError("the fixture's stop angle was not read at power-on")
    return part.stop_angle


def _limit_text(value: float | None) -> str:
    return "none" if value is None else f"{value:.3g}"


def _take_back(part: PartRun, name: str, condition: str) -> RemeasuredFirst:
    """Take a judged measurement off the part's record (it is measured again); what it was,
    with its stop-method scale, for `analysis.remeasured`."""
    m = next(m for m in reversed(part.record.measurements)
             if m.name == name and m.condition == condition)
    part.record.measurements.remove(m)
    label = f"{name}@{condition}"
    if label in part.failed_limits:
        part.failed_limits.remove(label)
    stop = part.record.analysis.stop_method.get(condition)
    return RemeasuredFirst(value=m.value, outcome=m.outcome.value, low=m.low, high=m.high,
                           scale_stop=None if stop is None else stop.scale,
                           u_scale_stop=None if stop is None else stop.u_scale)


@dataclass(frozen=True)
class StopRecord:
    """The station times of a stop-method record and the encoder's travel over its moves."""

    t_start: float
    t_end: float
    encoder_angle_deg: float
    u_encoder_angle_deg: float  # k=1: each end quantised to one count, averaged over moves


def stop_moves(ctx: RunContext, far: Callable[[], float], *, move_time_s: float,
               static_s: float, repeats: int, timeout_s: float) -> StopRecord:
    """The table to rest at the first stop of this turn, then rest, move to the second stop
    (`far()` deg on), rest, move back, rest, `repeats` times (steps stop_method and
    ramp_calibration)."""
    table = ctx.instruments.need_table()
    table.enable()
    table.set_rate(0.0)
    table.wait_at_rate(timeout_s)
    # The stops sit at fixed table angles: go to the first stop of this turn rather than
    # re-zeroing the encoder where the sweep happened to end, so every condition uses
    # the same stops and table angles stay comparable across the whole run.
    _, here = ctx.instruments.snapshot()
    origin = 360.0 * round(here.position_deg / 360.0)
    if abs(here.position_deg - origin) > AT_STOP_TOLERANCE_DEG:
        table.move_to(origin, move_time_s=move_time_s)
        table.wait_in_position(timeout_s)
    t_start = ctx.wait.clock.now_s()
    _, rest = ctx.instruments.snapshot()
    positions = [rest.position_deg]
    ctx.wait.sleep(static_s)
    far_deg = far()
    for _ in range(repeats):
        for target in (origin + far_deg, origin):
            table.move_to(target, move_time_s=move_time_s)
            table.wait_in_position(timeout_s)
            ctx.wait.sleep(static_s)
            _, rest = ctx.instruments.snapshot()
            positions.append(rest.position_deg)
    t_end = ctx.wait.clock.now_s()
    travel = np.abs(np.diff(positions))
    count_deg = 360.0 / table.counts_per_rev()  # the table driver's encoder resolution
    return StopRecord(t_start, t_end, float(travel.mean()),
                      count_deg * math.sqrt(2.0 / 12.0) / math.sqrt(travel.size))


def stop_result(ctx: RunContext, part: PartRun, data: dict[str, Any], ref: float,
                u_ref: float, noise: NoiseModel | None = None) -> StopMethodResult:
    """The stop-method analysis of one part's window against the reference angle, with
    `noise` (default: `stop_noise_model`); an AnalysisError when no move gives a scale."""
    result = analyze_stop_method(
        data["time_s"],
        data["rate_dps"],
        ref,
        u_ref,
        status=data["status"],
        settings=StopMethodSettings(
            full_scale_dps=ctx.product.range_dps, trim_leading_motion=True
        ),
        noise=noise or stop_noise_model(ctx, part),
    )
    if result.scale is None or result.u_scale is None:
        raise AnalysisError("no usable move: " + "; ".join(result.warnings))
    return result


def stop_results(result: StopMethodResult, reference: str) -> StopMethodResults:
    """The record's section for one stop-method record (analysis.stop_method's entries)."""
    return StopMethodResults(
        bias_dps=result.bias_dps,
        bias_correction_dps=result.bias_correction_dps,
        scale_correction=result.scale_correction,
        scale=result.scale,
        u_scale=result.u_scale,
        reference_angle_deg=result.reference_angle_deg,
        u_reference_angle_deg=result.u_reference_angle_deg,
        reference=reference,
        static_windows=[[a, b] for a, b in result.static_segments_s],
        moves=[
            StopMove(
                start_s=m.start_s,
                end_s=m.end_s,
                measured_angle_deg=m.measured_angle_deg,
                scale_correction=m.scale_correction,
            )
            for m in result.moves
        ],
        warnings=list(result.warnings),
    )


class StopSettings(StepSettings):
    stop_angle_deg: float = Field(90.0, gt=0, le=360, description="angle between the stops")
    move_time_s: float = Field(3.5, gt=0, le=ONE_HOUR_S, description="duration of each smooth move")
    static_s: float = Field(
        5.0, gt=0, le=ONE_HOUR_S, description="rest before, between and after the moves"
    )
    bias_window_s: float = Field(
        3.0, gt=0, le=ONE_HOUR_S, description="leading rest used for the bias"
    )
    repeats: int = Field(1, ge=1, le=MAX_REPEATS, description="out-and-back pairs")
    reference: Literal["encoder", "fixture"] = Field(
        "encoder", description="angle reference: the table encoder or the fixture's stop angle"
    )
    move_timeout_s: Seconds = Field(60.0, gt=0, description="time allowed for a move")


class VerifyStopSettings(StopSettings):
    supply_v: Volts | None = Field(
        None, description="supply during verification (default: the product's V0)"
    )


class StopMethod(StepType[Any]):
    """The article's stop method at one condition, the table moving the part between stops."""

    type_name = "stop_method"
    Settings = StopSettings
    uses_table = True
    provides = frozenset({Provided.SCALE_STOP})
    Results: ClassVar[type[BaseModel] | None] = StopMethodResults
    _again = False  # True while the stop moves are measured once more (a lone failure)

    @classmethod
    def measurements(cls, settings: Any) -> list[Declared]:
        return [Declared("stop_table_consistency", "1", "(stop scale - table scale) / combined "
                         "standard (k=1) uncertainty; needs a rate-table fit at the condition",
                         per_condition=True, optional=True)]

    def estimate_s(self, ctx: RunContext) -> float:
        cfg = self.settings
        return cfg.static_s + cfg.repeats * 2 * (cfg.move_time_s + cfg.static_s + 1.0) + 2.0

    def main(self, ctx: RunContext) -> None:
        t_start, t_end = self._moves(ctx)
        ctx.parts.each(lambda part: self._analyse(ctx, part, t_start, t_end))
        self._remeasure_lone_failures(ctx)

    def _remeasure_lone_failures(self, ctx: RunContext) -> None:
        """A part whose only failure is the consistency judgement here has the stop moves at
        this condition measured once more before its verdict (the table and chamber are still
        at it); the second judgement stands and the first is kept on the record
        (`analysis.remeasured`). The stop scale holds nearly all of E_n's variance (its u is
        ~10x the table's), so the second E_n is nearly independent of the first: a good part
        is rejected only if both fail, a bad one fails again."""
        label = f"stop_table_consistency@{self.condition}"
        lone = [p for p in ctx.parts.alive() if failed_limits(p) == [label]]
        if not lone:
            return
        firsts = {p.socket: _take_back(p, "stop_table_consistency", self.condition) for p in lone}
        for part in lone:
            first = firsts[part.socket]
            ctx.records.event(
                f"socket {part.socket}: {label} failed alone (E_n {first.value:+.2f}, "
                f"limits {_limit_text(first.low)}..{_limit_text(first.high)}): the "
                f"stop moves at {self.condition} are measured once more before the verdict",
                "WARNING", [part],
            )
        t_start, t_end = self._moves(ctx)
        self._again = True
        for part in lone:
            if not part.alive:
                continue
            ctx.parts.per_part(part, lambda p: self._analyse(ctx, p, t_start, t_end))
            second = next((m for m in reversed(part.record.measurements)
                           if m.name == "stop_table_consistency"
                           and m.condition == self.condition), None)
            part.record.analysis.remeasured.append(RemeasuredResults(
                measurement="stop_table_consistency",
                condition=self.condition,
                why="the part failed only this judgement: the stop moves were measured "
                    "once more and the second judgement stands",
                first=firsts[part.socket],
                second=None if second is None else RemeasuredSecond(
                    value=second.value, outcome=second.outcome.value),
            ))
        ctx.parts.require()

    def _moves(self, ctx: RunContext) -> tuple[float, float]:
        """The table moves the parts between the stops; the station times of the record."""
        cfg = self.settings

        def far() -> float:
            if cfg.reference == "fixture":
                # the stops are the fixture's: move to its measured angle (mean over sockets)
                return float(np.mean([stop_angle(p)[0] for p in ctx.parts.alive()]))
            return float(cfg.stop_angle_deg)

        rec = stop_moves(ctx, far, move_time_s=cfg.move_time_s, static_s=cfg.static_s,
                         repeats=cfg.repeats, timeout_s=cfg.move_timeout_s)
        self._encoder_angle, self._encoder_u = rec.encoder_angle_deg, rec.u_encoder_angle_deg
        return rec.t_start, rec.t_end

    def _scale(
        self, ctx: RunContext, part: PartRun, data: dict[str, Any]
    ) -> tuple[StopMethodResult, float, float, float, float]:
        """Stop-method analysis of a window against this step's reference angle: the result,
        scale, its standard uncertainty, the reference angle and its uncertainty."""
        cfg = self.settings
        if cfg.reference == "fixture":
            ref, u_ref = stop_angle(part)
        else:
            ref, u_ref = self._encoder_angle, self._encoder_u
        result = stop_result(ctx, part, data, ref, u_ref)
        assert result.scale is not None and result.u_scale is not None
        return result, result.scale, result.u_scale, ref, u_ref

    def _analyse(self, ctx: RunContext, part: PartRun, t0: float, t1: float) -> None:
        cfg = self.settings
        res = part.conditions[self.condition]
        data = samples_between(ctx, part, t0, t1)
        if not check_window(
            ctx,
            part,
            data,
            f"stop method at {self.condition}",
            cfg.static_s * (2 * cfg.repeats + 1),
        ):
            return
        try:
            result, scale, u_scale, ref, u_ref = self._scale(ctx, part, data)
        except AnalysisError as exc:
            ctx.parts.drop(part, Verdict.ERROR, f"stop method at {self.condition}: {exc}")
            return
        res.note_temperature("scale", data["temp_c"], data["time_s"])
        res.stop = StopScale(scale, u_scale, result.bias_dps, ref, u_ref)
        self._segments(ctx, part, res, result, ref)
        part.record.analysis.stop_method[self.condition] = stop_results(result, cfg.reference)
        if res.table_fit is not None:
            self._judge_consistency(ctx, part, result, res.table_fit)

    def _segments(self, ctx: RunContext, part: PartRun, res: ConditionResult,
                  result: StopMethodResult, ref: float) -> None:
        """raw.h5 /segments: the static windows and the moves of the stop record."""
        for i, (a, b) in enumerate(result.static_segments_s):
            ctx.records.segment(
                part,
                "stop_static",
                i,
                a,
                b,
                ref_rate_dps=0.0,
                temp_setpoint_c=res.temperature_c,
                supply_v=res.supply_v,
            )
        for i, mv in enumerate(result.moves):
            ctx.records.segment(
                part,
                "stop_move",
                i,
                mv.start_s,
                mv.end_s,
                ref_angle_deg=ref * (1 if mv.direction > 0 else -1),
                temp_setpoint_c=res.temperature_c,
                supply_v=res.supply_v,
            )

    def _judge_consistency(self, ctx: RunContext, part: PartRun, result: StopMethodResult,
                           table_fit: RateTableFit) -> None:
        """stop_table_consistency: the stop scale against the rate table's at this condition."""
        try:
            cons = stop_vs_rate_table(result, table_fit)
        except AnalysisError as exc:
            ctx.records.event(
                f"socket {part.socket}: consistency not computed: {exc}", "WARNING", [part]
            )
            return
        ctx.records.measure(
            part,
            "stop_table_consistency",
            cons.normalised_difference,
            units="1",
            condition=self.condition,
            description="(stop scale - table scale) / combined standard (k=1) uncertainty"
            + ("; measured again: the first judgement at this condition failed alone"
               if self._again else ""),
        )


class VerifyStop(StopMethod):
    """Verification without a rate table: the stop moves again, now on the part's own
    compensated output; the residual scale error is the compensated scale minus one."""

    type_name = "verify_stop"
    Settings = VerifyStopSettings
    provides = frozenset()
    Results = Verification

    @classmethod
    def requires(cls, settings: Any) -> set[Provided]:
        return {Provided.PROGRAMMED}

    @classmethod
    def measurements(cls, settings: Any) -> list[Declared]:
        return [
            Declared("residual_bias_dps", "deg/s", "compensated output at rest (stop method)"),
            Declared("residual_scale_error", "1", "compensated stop-method scale - 1"),
        ]

    def setup(self, ctx: RunContext) -> None:
        supply_v = ctx.product.reference_supply_v
        if self.settings.supply_v is not None:
            supply_v = self.settings.supply_v
        ctx.instruments.set_supply_voltage(supply_v)
        self.supply_v = supply_v

    def _analyse(self, ctx: RunContext, part: PartRun, t0: float, t1: float) -> None:
        cfg = self.settings
        data = samples_between(ctx, part, t0, t1)
        if not check_window(ctx, part, data, "verification (stop moves)", cfg.static_s * 3):
            return
        try:
            result, scale, u_scale, ref, u_ref = self._scale(ctx, part, data)
        except AnalysisError as exc:
            ctx.parts.drop(part, Verdict.ERROR, f"verification (stop moves): {exc}")
            return
        ctx.records.measure(
            part,
            "residual_bias_dps",
            result.bias_dps,
            units="deg/s",
            uncertainty_k2=2 * result.bias.u_bias_dps,
            condition="verify",
            description="compensated output at rest (stop method)",
        )
        ctx.records.measure(
            part,
            "residual_scale_error",
            scale - 1.0,
            units="1",
            uncertainty_k2=2 * u_scale,
            condition="verify@stop",
            description="compensated stop-method scale - 1",
        )
        for i, mv in enumerate(result.moves):
            ctx.records.segment(
                part,
                "verify",
                i,
                mv.start_s,
                mv.end_s,
                ref_angle_deg=ref * (1 if mv.direction > 0 else -1),
                supply_v=self.supply_v,
            )
        part.record.verification = Verification(
            method="stop_method",
            # the move's mean rate stands for "the rate" of a stop-method verification
            residuals=[
                VerificationRow(
                    condition="verify@stop",
                    rate_in_dps=ref / cfg.move_time_s,
                    error_dps=(scale - 1.0) * ref / cfg.move_time_s,
                    error_pct=100 * (scale - 1.0),
                    u_error_pct_k2=200 * u_scale,
                )
            ],
            residual_bias_dps=result.bias_dps,
            max_error_pct=abs(100 * (scale - 1.0)),
            supply_v=self.supply_v,
        )
