"""The stability window judged after the measurement it overlapped (`thermal` step,
`overlap_measurement`), and the condition measured again for a part whose window fails.

With the setting the thermal step hands over to the condition's measurement steps as soon as
every die meets the criterion over a shorter span; the plan adds this step after them
(`Stabilise.after_condition`). It judges each part's die over the span from the start of the
measurement to its end, every `window_s` window in it (after one full window at least). A
part whose span fails is never accepted on that measurement: its first attempt is taken off
the judged record and kept in `analysis.measured_again` with the reason, and the condition is
measured again for it: the thermal step as without the setting (a full window judged before
the measurement), then the same measurement steps, which the engine runs next for those
parts only (`follow_up`, `StepType.sockets`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from procedures.analysis.stability import StabilityVerdict, judge_span
from procedures.runtime.record import Outcome
from procedures.runtime.results import FirstMeasurement, MeasuredAgainResults, StabilityResults
from procedures.runtime.run_context import RunContext
from procedures.runtime.run_parts import PartRun
from procedures.steps.registry import StepPolicy, StepType

if TYPE_CHECKING:
    from procedures.steps.thermal import Stabilise


class JudgedAfter(StepType[Any]):
    """The condition's stability window, judged over its measurement (added by the plan)."""

    type_name = "thermal_judged_after"

    def __init__(self, thermal: Stabilise, measure: list[StepType[Any]]) -> None:
        super().__init__(thermal.settings, thermal.place, StepPolicy(
            timeout_s=thermal.policy.timeout_s))
        self.thermal = thermal
        self.measure = measure
        self.again: frozenset[int] = frozenset()  # the sockets measured again

    def estimate_s(self, ctx: RunContext) -> float:
        return 0.0

    def main(self, ctx: RunContext) -> None:
        starts = {p.socket: self._start_of(p) for p in ctx.parts.alive()}
        judged = {s: t for s, t in starts.items() if t is not None}
        if judged:  # one full window at least after the measurement started
            ctx.wait.sleep(max(0.0, max(judged.values()) + self.settings.window_s
                               - ctx.wait.clock.now_s()))
        failed: list[PartRun] = []
        for part in ctx.parts.alive():
            start = judged.get(part.socket)
            if start is None:
                continue
            verdict = self._judge(ctx, part, start)
            self._note(ctx, part, verdict)
            if not verdict.stable:
                failed.append(part)
        for part in failed:
            self._take_back(ctx, part)
        self.again = frozenset(p.socket for p in failed)

    def _start_of(self, part: PartRun) -> float | None:
        stab = part.record.analysis.stability.get(self.condition)
        return None if stab is None else stab.measurement_start_station_s

    def _judge(self, ctx: RunContext, part: PartRun, start_s: float) -> StabilityVerdict:
        st = self.settings
        assert part.stream is not None
        data = part.stream.window(part.stream.fixture_time(start_s), np.inf)
        return judge_span(data["time_s"], data["temp_c"], st.window_s, st.check_interval_s,
                          st.slope_c_per_min, st.band_c, self.place.condition.temperature_c
                          if self.place.condition else None, st.target_tolerance_c)

    def _note(self, ctx: RunContext, part: PartRun, v: StabilityVerdict) -> None:
        """The verdict on the part's stability record (and the condition's)."""
        stab = part.record.analysis.stability[self.condition]
        stab.stable = v.stable
        stab.after_slope_c_per_min = v.slope_c_per_min
        stab.after_band_c = v.band_c
        stab.judged_until_station_s = ctx.wait.clock.now_s()
        if self.condition in part.conditions:
            part.conditions[self.condition].stable = v.stable

    def _take_back(self, ctx: RunContext, part: PartRun) -> None:
        """The first attempt off the judged record, kept in `analysis.measured_again`."""
        stab = part.record.analysis.stability[self.condition]
        since = self.thermal.measured_from.get(part.socket, len(part.record.measurements))
        first = part.record.measurements[since:]
        del part.record.measurements[since:]
        for m in first:
            label = f"{m.name}@{m.condition}" if m.condition else m.name
            if m.outcome is Outcome.FAIL and label in part.failed_limits:
                part.failed_limits.remove(label)
        why = (
            f"the die was not stable over the measurement: the {self.settings.window_s:g} s "
            f"window judged afterwards had slope {stab.after_slope_c_per_min:.3f} C/min and "
            f"band {stab.after_band_c:.3f} C (limits {self.settings.slope_c_per_min:g} C/min, "
            f"{self.settings.band_c:g} C)"
        )
        part.record.analysis.measured_again.append(MeasuredAgainResults(
            condition=self.condition, why=why,
            first_stability=StabilityResults.model_validate(stab.model_dump()),
            first=[FirstMeasurement(name=m.name, condition=m.condition, value=m.value,
                                    outcome=m.outcome.value, low=m.low, high=m.high)
                   for m in first],
        ))
        ctx.records.event(
            f"socket {part.socket}: {self.condition} measured again: {why}; the first "
            f"attempt ({len(first)} measurement(s)) is kept in analysis.measured_again",
            "WARNING", [part],
        )

    def follow_up(self) -> list[StepType[Any]]:
        """For the parts whose window failed: the thermal step as without the setting, then
        the condition's measurement steps again."""
        if not self.again:
            return []
        settings = self.thermal.settings.model_copy(
            update={"overlap_measurement": False, "supply_change_no_wait": False})
        steps: list[StepType[Any]] = [type(self.thermal)(settings, self.place,
                                                         self.thermal.policy)]
        steps += [type(s)(s.settings, s.place, s.policy) for s in self.measure]
        for step in steps:
            step.sockets = self.again
        return steps
