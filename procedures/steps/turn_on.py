"""turn_on_repeatability: IEEE 1431 turn-on to turn-on bias repeatability.

N times: supply off, wait `off_s`, supply on, wait `settle_s` (the warm-up the
specification allows), measure the bias over `dwell_s`. The repeatability is the sample
standard deviation of the N biases (procedures.analysis.turn_on); measurement
`turn_on_bias_repeatability_dps` (pinned). The parts are left powered and streaming.
"""

from __future__ import annotations

from functools import partial
from typing import Any

from pydantic import Field

from common.bounded import ONE_HOUR_S
from procedures.analysis.allan import analyze_allan
from procedures.analysis.bias import estimate_bias
from procedures.analysis.errors import AnalysisError
from procedures.analysis.turn_on import turn_on_repeatability
from procedures.runtime.record import Verdict
from procedures.runtime.results import TurnOnResults
from procedures.runtime.run_context import RunContext
from procedures.runtime.run_parts import PartRun
from procedures.steps.base import check_window, sample_rate_hz, samples_between
from procedures.steps.power_cycle import power_off, power_on, supply_level_v
from procedures.steps.registry import Declared, StepSettings, StepType

MEASUREMENT = "turn_on_bias_repeatability_dps"  # pinned


class TurnOnSettings(StepSettings):
    turn_ons: int = Field(5, ge=3, le=100, description="power-ons, each with its bias")
    off_s: float = Field(10.0, gt=0, le=ONE_HOUR_S, description="supply off before each, s")
    settle_s: float = Field(
        5.0, ge=0, le=ONE_HOUR_S, description="after power-on, before the bias window, s"
    )
    dwell_s: float = Field(10.0, ge=1.0, le=ONE_HOUR_S, description="bias window, s")


class TurnOnRepeatability(StepType[TurnOnSettings]):
    """Power off, wait, power on, bias; N times; the standard deviation of the biases."""

    type_name = "turn_on_repeatability"
    Results = TurnOnResults
    Settings = TurnOnSettings

    @classmethod
    def measurements(cls, settings: Any) -> list[Declared]:
        return [Declared(MEASUREMENT, "deg/s", "turn-on to turn-on bias repeatability (1 sigma)")]

    def estimate_s(self, ctx: RunContext) -> float:
        s = self.settings
        return s.turn_ons * (s.off_s + s.settle_s + s.dwell_s + 1.0)

    def main(self, ctx: RunContext) -> None:
        s = self.settings
        cond = self.place.condition
        level_v = supply_level_v(ctx, cond.supply_v if cond is not None else None)
        biases: dict[int, list[tuple[float, float]]] = {p.socket: [] for p in ctx.parts.alive()}
        for i in range(s.turn_ons):
            power_off(ctx)
            ctx.wait.sleep(s.off_s)
            on_s = power_on(ctx, level_v)
            ctx.wait.sleep(max(on_s + s.settle_s - ctx.wait.now_s(), 0.0))
            t0 = ctx.wait.now_s()
            ctx.wait.sleep(s.dwell_s)
            t1 = ctx.wait.now_s()
            ctx.parts.each(partial(self._bias, ctx, window=(i, t0, t1), biases=biases))
        ctx.records.event(f"turn-on repeatability: {s.turn_ons} power-ons at {level_v:g} V")
        ctx.parts.each(lambda part: self._judge(ctx, part, biases[part.socket]))

    def _bias(
        self, ctx: RunContext, part: PartRun, *, window: tuple[int, float, float],
        biases: dict[int, list[tuple[float, float]]],
    ) -> None:
        i, t0, t1 = window
        data = samples_between(ctx, part, t0, t1)
        what = f"turn-on {i + 1} bias"
        if not check_window(ctx, part, data, what, self.settings.dwell_s):
            return
        fs = sample_rate_hz(ctx)
        try:
            noise = part.noise or analyze_allan(data["rate_dps"], fs).noise.model
            est = estimate_bias(data["rate_dps"], fs, noise)
        except AnalysisError as exc:
            ctx.parts.drop(part, Verdict.ERROR, f"{what}: {exc}")
            return
        biases[part.socket].append((est.bias_dps, est.u_bias_dps))

    def _judge(self, ctx: RunContext, part: PartRun, biases: list[tuple[float, float]]) -> None:
        try:
            result = turn_on_repeatability([b for b, _ in biases], [u for _, u in biases])
        except AnalysisError as exc:
            ctx.parts.drop(part, Verdict.ERROR, f"turn-on repeatability: {exc}")
            return
        key = self.place.condition_name or "run"
        part.record.analysis.turn_on_repeatability[key] = TurnOnResults.model_validate({
            **result.as_dict(),
            "off_s": self.settings.off_s,
            "settle_s": self.settings.settle_s,
            "dwell_s": self.settings.dwell_s,
        })
        ctx.records.measure(
            part,
            MEASUREMENT,
            result.repeatability_dps,
            units="deg/s",
            uncertainty_k2=2.0 * result.u_repeatability_dps,
            condition=self.place.condition_name or None,
            description=f"turn-on to turn-on bias repeatability, std of {result.n} biases",
        )
