"""warm_up: bias against time from power-on until it settles; measurement `warm_up_time_s`.

The supply goes off for `off_s` (the part cools and its transient resets), then on; the
output at rest is recorded for `duration_s` from power-on and the warm-up time is when a
fitted exponential has decayed into +/-`band_dps` of its final value
(procedures.analysis.warm_up). A part that has not settled within the record gets the
fit's extrapolation, with a warning. The parts are left powered and streaming.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from pydantic import Field

from common.bounded import ONE_DAY_S
from procedures.analysis.errors import AnalysisError
from procedures.analysis.warm_up import DEFAULT_WINDOWS, MIN_WINDOWS, warm_up_time
from procedures.runtime.record import Verdict
from procedures.runtime.results import WarmUpResults
from procedures.runtime.run_context import RunContext
from procedures.runtime.run_parts import PartRun
from procedures.steps.base import check_window, samples_between
from procedures.steps.power_cycle import power_off, power_on, supply_level_v
from procedures.steps.registry import Declared, StepSettings, StepType

MEASUREMENT = "warm_up_time_s"  # pinned


class WarmUpSettings(StepSettings):
    off_s: float = Field(60.0, gt=0, le=ONE_DAY_S, description="supply off before power-on, s")
    duration_s: float = Field(
        600.0, ge=10.0, le=ONE_DAY_S, description="record from power-on, s"
    )
    band_dps: float = Field(
        0.01, gt=0, le=100.0, description="settled: within +/- this of the final bias, deg/s"
    )
    windows: int = Field(
        DEFAULT_WINDOWS, ge=MIN_WINDOWS, le=1000, description="averaging windows in the record"
    )


class WarmUp(StepType[WarmUpSettings]):
    """Power the part on from cold and time its bias transient into a band."""

    type_name = "warm_up"
    Results = WarmUpResults
    Settings = WarmUpSettings

    @classmethod
    def measurements(cls, settings: Any) -> list[Declared]:
        return [Declared(MEASUREMENT, "s", "time from power-on until the bias settles")]

    def estimate_s(self, ctx: RunContext) -> float:
        return self.settings.off_s + self.settings.duration_s + 1.0

    def main(self, ctx: RunContext) -> None:
        s = self.settings
        cond = self.place.condition
        power_off(ctx)
        ctx.wait.sleep(s.off_s)
        on_s = power_on(ctx, supply_level_v(ctx, cond.supply_v if cond is not None else None))
        ctx.wait.sleep(max(on_s + s.duration_s - ctx.wait.now_s(), 0.0))
        end_s = ctx.wait.now_s()
        ctx.parts.each(lambda part: self._analyse(ctx, part, on_s, end_s))

    def _analyse(self, ctx: RunContext, part: PartRun, on_s: float, end_s: float) -> None:
        s = self.settings
        data = samples_between(ctx, part, on_s, end_s)
        if not check_window(ctx, part, data, "warm-up record", end_s - on_s):
            return
        assert part.stream is not None
        t = np.asarray(data["time_s"], dtype=float) - part.stream.fixture_time(on_s)
        try:
            w = warm_up_time(t, data["rate_dps"], s.band_dps, s.windows)
        except AnalysisError as exc:
            ctx.parts.drop(part, Verdict.ERROR, f"warm-up: {exc}")
            return
        key = self.place.condition_name or "run"
        part.record.analysis.warm_up[key] = WarmUpResults.model_validate(w.as_dict())
        if not w.settled_in_record:
            ctx.records.event(
                f"socket {part.socket}: the bias had not settled within +/-{s.band_dps:g} deg/s "
                f"by the end of the {s.duration_s:g} s record; the warm-up time "
                f"{w.warm_up_time_s:.0f} s is extrapolated from the fit (lengthen duration_s)",
                level="WARNING",
                parts=[part],
            )
        ctx.records.measure(
            part,
            MEASUREMENT,
            w.warm_up_time_s,
            units="s",
            uncertainty_k2=2.0 * w.u_warm_up_time_s,
            condition=self.place.condition_name or None,
            description=f"power-on until the bias is within +/-{s.band_dps:g} deg/s of final "
            "(fitted exponential)",
        )
