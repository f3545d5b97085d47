"""The article's stop method inside the ramp: at each end of the span the table rests,
turns the parts through `stop_angle_deg` and back (`moves_per_direction` times), resting
between, in place of the plateaus it would have cycled through meanwhile.

Near the top the record starts once every die is slower than the ramp's
`static_below_c_per_min` after the turn (the dies at their peak, their bias hardly moving
between the leading rest and the moves); near the bottom after the static dwell, under the
same condition. Each record is analysed as the `stop_method` step analyses its own
(procedures/steps/stop.py: the bias from the leading rest, the scale from the integrated
moves against the encoder's travel). After the ramp's fit, the stop scale is compared with
the fitted scale law at the record's die temperature (the element's: less the fitted lag
x the die's rate) and supply: E_n with both k=1 uncertainties
(procedures/analysis/consistency.py), recorded as `stop_table_consistency@ramp_<end>` and
judged against the same per-condition limit as eol-rate-table's (the judgements counted
per end), and in `analysis.ramp_stop`. The ramp cannot measure an end again (the dies have
moved on), so a failed judgement stands.

The stop scale's u rests on the part's bias wander between the leading rest and the moves.
Both records are judged with the static dwell's noise model (the top's, made before the
dwell, analysed again), every term the dwell shows kept (`ramp_static.wander_model`) and
the product's typical as a floor: with the typical alone, a part wandering more than it
(SIM-0002 at 23.9 deg/h, typical 15) had its u some 20 % short and failed falsely.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Literal

import numpy as np
from pydantic import Field, model_validator

from common.bounded import MAX_REPEATS
from procedures.analysis.allan import NoiseModel
from procedures.analysis.consistency import Consistency, normalised_difference
from procedures.analysis.errors import AnalysisError
from procedures.analysis.ramp_fit import RampFit, law_uncertainties
from procedures.analysis.stop_method import StopMethodResult
from procedures.runtime.record import Verdict
from procedures.runtime.results import RampStopEnd, RampStopResults
from procedures.runtime.run_context import RunContext
from procedures.runtime.run_parts import PartRun
from procedures.steps.base import check_window, samples_between
from procedures.steps.registry import Declared, StepSettings
from procedures.steps.stop import (
    StopRecord,
    stop_moves,
    stop_noise_model,
    stop_result,
    stop_results,
)

End = Literal["top", "bottom"]
ENDS: tuple[End, ...] = ("top", "bottom")

CONSISTENCY = Declared(
    "stop_table_consistency", "1", "(stop scale - the ramp fit's scale at the record's die "
    "temperature and supply) / combined standard (k=1) uncertainty, at each end of the ramp",
    per_condition=True, optional=True)


class RampStopSettings(StepSettings):
    """The stop method at the ends of the ramp (as the `stop_method` step's settings)."""

    stop_angle_deg: float = Field(90.0, gt=0, le=360, description="angle between the stops")
    move_time_s: float = Field(3.5, gt=0, le=60, description="duration of each smooth move")
    static_s: float = Field(5.0, gt=0, le=120, description="rest before, between and after "
                            "the moves")
    bias_window_s: float = Field(3.0, gt=0, le=120, description="leading rest for the bias "
                                 "(at most static_s)")
    moves_per_direction: int = Field(1, ge=1, le=MAX_REPEATS, description="moves each way "
                                     "at each end (out-and-back pairs)")
    ends: list[End] = Field(
        default_factory=lambda: list(ENDS), min_length=1, max_length=2,
        description="where: near the top (the dies at their peak) and/or near the bottom "
        "(after the static dwell)")
    move_timeout_s: float = Field(60.0, gt=0, le=600, description="time allowed for a move")

    @model_validator(mode="after")
    def _window_in_rest(self) -> RampStopSettings:
        if self.bias_window_s > self.static_s:
            raise ValueError(f"bias_window_s ({self.bias_window_s:g} s) must not exceed "
                             f"static_s ({self.static_s:g} s)")
        if len(set(self.ends)) != len(self.ends):
            raise ValueError("give each end once")
        return self

    def record_s(self) -> float:
        """Station time of one record, the table's stop and the move to the first stop in."""
        moves = 2 * self.moves_per_direction
        return self.static_s * (moves + 1) + self.move_time_s * (moves + 1) + 2.0


@dataclass(frozen=True)
class StopAtEnd:
    """One part's stop-method record at one end of the ramp, before the fit."""

    end: str
    result: StopMethodResult
    die_temp_c: float
    die_rate_c_per_s: float
    supply_v: float
    station_s: float
    data: dict[str, Any]  # the part's samples of the record (analysed again in `judge`)
    reference: tuple[float, float]  # the encoder's travel and its k=1 uncertainty, deg

    @property
    def label(self) -> str:
        return f"ramp_{self.end}"


def run_stop(ctx: RunContext, st: RampStopSettings, end: str,
             logs: dict[int, list[StopAtEnd]], noise: dict[int, NoiseModel]) -> None:
    """The stop-method record at `end` for every part, each analysed at once (with its
    noise model from the static dwell where it has one)."""
    rec = stop_moves(ctx, lambda: float(st.stop_angle_deg), move_time_s=st.move_time_s,
                     static_s=st.static_s, repeats=st.moves_per_direction,
                     timeout_s=st.move_timeout_s)
    volts = ctx.instruments.log_supply()[0]
    for part in ctx.parts.alive():
        ctx.parts.per_part(part, lambda p: _analyse(ctx, p, st, rec, (end, volts), logs,
                                                    noise.get(p.socket)))


def _analyse(ctx: RunContext, part: PartRun, st: RampStopSettings, rec: StopRecord,
             where: tuple[str, float], logs: dict[int, list[StopAtEnd]],
             noise: NoiseModel | None) -> None:
    end, volts = where
    data = samples_between(ctx, part, rec.t_start, rec.t_end)
    what = f"stop method at the ramp's {end}"
    if not check_window(ctx, part, data, what, st.static_s * (2 * st.moves_per_direction + 1)):
        return
    ref = (rec.encoder_angle_deg, rec.u_encoder_angle_deg)
    try:
        result = _stop_scale(ctx, part, data, ref, noise)
    except AnalysisError as exc:
        ctx.parts.drop(part, Verdict.ERROR, f"{what}: {exc}")
        return
    t = np.asarray(data["time_s"], dtype=np.float64)
    temp = np.asarray(data["temp_c"], dtype=np.float64)
    slope = float(np.polyfit(t - t.mean(), temp, 1)[0]) if t.size > 2 else 0.0
    stop = StopAtEnd(end, result, float(temp.mean()), slope, volts, rec.t_start, data, ref)
    logs.setdefault(part.socket, []).append(stop)
    _segments(ctx, part, stop)


def _stop_scale(ctx: RunContext, part: PartRun, data: dict[str, Any],
                ref: tuple[float, float], noise: NoiseModel | None) -> StopMethodResult:
    """The record analysed with the part's noise model where the run set one, else with
    `noise` (the static dwell's, see `ramp_static.wander_model`) or, before the dwell, the
    record's own leading rest's, floored (`_floored`)."""
    result = stop_result(ctx, part, data, *ref, noise=stop_noise_model(ctx, part))
    if stop_noise_model(ctx, part) is None:  # the ramp sets none: floor the record's own
        model = noise if noise is not None else result.bias.noise
        result = stop_result(ctx, part, data, *ref, noise=_floored(ctx, model))
    return result


def with_dwell_noise(ctx: RunContext, part: PartRun, stop: StopAtEnd,
                     noise: NoiseModel | None) -> StopAtEnd:
    """The record analysed again with the static dwell's noise model, which a record made
    before the dwell (the top's) did not have: its u then covers the part's own bias wander
    as far as the dwell shows it, not only the product's typical (a part wandering more
    than typical had its top's u short). Unchanged without a dwell."""
    if noise is None:
        return stop
    return replace(stop, result=_stop_scale(ctx, part, stop.data, stop.reference, noise))


def _floored(ctx: RunContext, noise: NoiseModel) -> NoiseModel:
    """A noise model (the static dwell's, or before it the record's own leading rest's)
    with the product's typical bias instability and rate random walk as floors: the bias
    wanders between the leading rest and the moves, which a few seconds of rest cannot
    show (as `stop_noise_model` floors the bias step's model)."""
    return noise.with_floor(ctx.product.bias_instability_deg_per_h / 3600.0,
                            ctx.product.rate_random_walk_deg_per_h_per_sqrt_h / 216000.0)


def _segments(ctx: RunContext, part: PartRun, stop: StopAtEnd) -> None:
    """raw.h5 /segments: the record's static windows and moves, under its label."""
    ref = stop.result.reference_angle_deg
    for i, (a, b) in enumerate(stop.result.static_segments_s):
        ctx.records.segment(part, "stop_static", i, a, b, ref_rate_dps=0.0,
                            supply_v=stop.supply_v, condition=stop.label)
    for i, mv in enumerate(stop.result.moves):
        ctx.records.segment(part, "stop_move", i, mv.start_s, mv.end_s,
                            ref_angle_deg=ref * (1 if mv.direction > 0 else -1),
                            supply_v=stop.supply_v, condition=stop.label)


def element_temp_c(fit: RampFit | None, stop: StopAtEnd) -> float:
    """The element's temperature during the record: the die's less the fitted lag x its
    rate (the die's own where the fit could not tell the lag)."""
    tau = 0.0 if fit is None or not np.isfinite(fit.tau_s) else float(fit.tau_s)
    return stop.die_temp_c - tau * stop.die_rate_c_per_s


def stop_vs_ramp(stop: StopMethodResult, fit: RampFit, temp_c: float, supply_v: float
                 ) -> tuple[Consistency, float, float]:
    """The stop scale (a) against the ramp fit's scale law (b) at (temp_c, supply_v), each
    with its k=1 uncertainty; the comparison, the law's scale and its u."""
    if stop.scale is None or stop.u_scale is None:
        raise AnalysisError("the stop method gave no scale")
    law = float(fit.coefficients.scale_at(temp_c, supply_v))
    u_law = law_uncertainties(fit, temp_c, supply_v)[1]
    return normalised_difference(stop.scale, stop.u_scale, law, u_law), law, u_law


def judge(ctx: RunContext, part: PartRun, fit: RampFit | None,
          stops: list[StopAtEnd], noise: NoiseModel | None = None) -> None:
    """Each end's stop scale against the fit (None: the fit failed; the stop records kept
    without a comparison), into analysis.ramp_stop and stop_table_consistency@ramp_<end>;
    each record analysed with the static dwell's noise model `noise` where there is one."""
    ends = []
    for stop in (with_dwell_noise(ctx, part, s, noise) for s in stops):
        temp = element_temp_c(fit, stop)
        entry = dict(label=stop.label, end=stop.end, station_s=stop.station_s,
                     die_temp_c=stop.die_temp_c, element_temp_c=temp,
                     die_rate_c_per_min=60.0 * stop.die_rate_c_per_s, supply_v=stop.supply_v,
                     stop=stop_results(stop.result, "encoder"))
        if fit is not None:
            cons, law, u_law = stop_vs_ramp(stop.result, fit, temp, stop.supply_v)
            entry.update(ramp_scale=law, u_ramp_scale=u_law,
                         normalised_difference=cons.normalised_difference)
            _measure(ctx, part, stop.label, cons)
        ends.append(RampStopEnd(**_given(entry)))
    if ends:
        part.record.analysis.ramp_stop = RampStopResults(ends=ends)


def _given(entry: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in entry.items() if v is not None}


def _measure(ctx: RunContext, part: PartRun, label: str, cons: Consistency) -> None:
    ctx.records.measure(part, CONSISTENCY.name, cons.normalised_difference, units="1",
                        condition=label, description=CONSISTENCY.description)
