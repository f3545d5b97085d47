"""Thermal stabilisation, judged on each part's own die temperature sensor.

The chamber air reaching its setpoint says nothing about the die, which lags by minutes.
The step first waits for the air (so a die that has not started moving is not mistaken for a
stable one), then judges every part on its own sensor: over the last `window_s`, the slope of
a straight-line fit and the peak-to-peak of one-second means must both be small. The window
must lie entirely after the condition was set. Measurement starts when every remaining part
is stable; a part that never gets there is dropped when the stability timeout runs out.

Two settings shorten the wait (docs/procedures.md, the faster options): `overlap_measurement`
hands over once every die meets the criterion over a shorter span and has the full window
judged after the measurement (procedures/steps/thermal_after.py); `supply_change_no_wait`
measures at once at a supply change whose predicted self-heating change meets the criterion.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from pydantic import Field, model_validator

from common.bounded import ONE_HOUR_S
from drivers.errors import ChamberSetpointNotReached
from procedures.analysis.stability import StabilityVerdict, change_settles, judge_stability
from procedures.runtime.record import Verdict
from procedures.runtime.results import StabilityResults
from procedures.runtime.run_context import RunContext
from procedures.runtime.run_parts import ConditionResult
from procedures.steps.registry import StepSettings, StepType
from procedures.steps.thermal_after import JudgedAfter
from procedures.steps.thermal_fastest import (
    control_settings,
    latest_reading_c,
    leave_at_target,
)
from procedures.thermal.chamber_strategy import (
    Criterion,
    DieState,
    ThermalModel,
    steady_die_c,
    straight_settle_s,
)
from procedures.thermal.thermal_control import (
    FastestController,
    heat_after_change,
    heat_now_c,
)
from procedures.units import Seconds


class ThermalSettings(StepSettings):
    """Thermal stability, judged on each part's own temperature sensor."""

    window_s: Seconds = Field(60.0, gt=0, description="window over which slope and band are judged")
    slope_c_per_min: float = Field(
        0.05, gt=0, le=100, description="largest |die temperature slope|"
    )
    band_c: float = Field(
        0.1, gt=0, le=100, description="largest peak-to-peak die temperature in the window"
    )
    target_tolerance_c: float | None = Field(
        None, gt=0, le=100, description="optional: die temperature within this of the setpoint"
    )
    stability_timeout_s: Seconds = Field(
        3600.0, gt=0, description="time allowed to reach stability (a part not stable by then "
        "is dropped)"
    )
    check_interval_s: float = Field(
        5.0, gt=0, le=ONE_HOUR_S, description="how often stability is evaluated"
    )
    overlap_measurement: bool = Field(
        False, description="measure as soon as every die meets the criterion over "
        "`overlap_entry_s` (entering stability), then judge the full window over the "
        "condition's measurements; a part whose window fails is measured again"
    )
    overlap_entry_s: Seconds = Field(
        20.0, gt=0, description="with overlap_measurement: the shorter span over which each "
        "die must meet the criterion before measurement starts (at most window_s)"
    )
    supply_change_no_wait: bool = Field(
        False, description="at a supply change at the same temperature: no wait when every "
        "part's predicted self-heating change meets the criterion (within band_c, its rate "
        "within slope_c_per_min); else it waits as without"
    )

    @model_validator(mode="after")
    def _entry_within_window(self) -> ThermalSettings:
        # only a setting in use is checked: a short window without the option stays valid
        if self.overlap_measurement and self.overlap_entry_s > self.window_s:
            raise ValueError(f"overlap_entry_s ({self.overlap_entry_s:g} s) is longer than "
                             f"window_s ({self.window_s:g} s): give at most the window")
        return self


def _heating_c(product: Any, supply_v: float) -> float:
    """A typical part's self-heating at `supply_v` (0 when the product gives no C/W)."""
    if not product.self_heating_c_per_w:
        return 0.0
    return steady_die_c(0.0, supply_v, product.typical_current_a, product.self_heating_c_per_w)


def _load_size(ctx: RunContext) -> int:
    """The parts the supply feeds: every one still running, also those a step run again
    for some parts only leaves out (the supply's current is the load's)."""
    return max(sum(1 for p in ctx.parts if p.alive), 1)


class Stabilise(StepType[ThermalSettings]):
    """Set the condition (chamber setpoint, supply level) and wait for every die to settle.

    Inside `for_each: condition` (the condition comes from the loop). With the procedure's
    `chamber.strategy: fastest` the chamber follows a planned overshoot profile (see "Thermal
    strategy" above) and is at the target when measurement starts."""

    type_name = "thermal"
    Results = StabilityResults
    Settings = ThermalSettings

    @property
    def target(self) -> Any:
        if self.place.condition is None:
            raise ValueError("the thermal step runs inside 'for_each: condition'")
        return self.place.condition

    def estimate_s(self, ctx: RunContext) -> float:
        """The settle time the thermal model predicts (chamber ramp, air and die lags, the
        self-heating's change with the supply), judged by this step's criterion. The first
        condition starts from the chamber where a run leaves it (its safe temperature) with
        the part just powered. A flat 20 min per temperature change and one window per
        supply change made the first estimate of eol-rate-table 54.5 min for a 43.6 min run."""
        st = self.settings
        cfg, product = ctx.procedure.chamber, ctx.product
        previous = self.place.previous
        if previous is None:
            start_c, heat0_c = cfg.safe_temp_c, 0.0
        else:
            start_c, heat0_c = previous.temperature_c, _heating_c(product, previous.supply_v)
        die = DieState(
            die_c=start_c + heat0_c, tau_s=product.die_tau_s, heat_c=heat0_c,
            heat_final_c=_heating_c(product, self.target.supply_v),
            heat_tau_s=product.self_heating_tau_s,
        )
        model = ThermalModel(cfg.air_tau_s, product.die_tau_s, cfg.ramp_c_per_min)
        crit = Criterion(st.window_s, st.slope_c_per_min, st.band_c)
        settle_s = straight_settle_s(model, start_c, die, self.target.temperature_c, crit)
        if not math.isfinite(settle_s):  # never within the model's horizon: its timeout
            return float(st.stability_timeout_s)
        return settle_s + 0.5 * st.check_interval_s  # judged every check_interval_s

    def setup(self, ctx: RunContext) -> None:
        self._control: FastestController | None = None
        self._changes: dict[int, float] = {}  # each part's predicted self-heating change, C
        self._no_wait = False
        self.measured_from: dict[int, int] = {}  # each part's measurements before measuring
        if ctx.procedure.chamber.strategy == "fastest":
            self._setup_fastest(ctx)
            return
        chamber, cfg = ctx.instruments.chamber, ctx.procedure.chamber
        if abs(chamber.read_setpoint() - self.target.temperature_c) > 0.05:
            chamber.set_ramp_rate(cfg.ramp_c_per_min)
            chamber.set_setpoint(self.target.temperature_c)
        if not chamber.is_running():
            chamber.run()
        # the supply's power before and after, read only where the prediction is asked for
        predict = self.settings.supply_change_no_wait and self.place.previous is not None
        power_old_w = self._power_each_w(ctx) if predict else 0.0
        ctx.instruments.set_supply_voltage(self.target.supply_v)
        if predict:
            self._predict_changes(ctx, power_old_w, self._power_each_w(ctx))
        self._no_wait = self._decide_no_wait(ctx)
        self._mark_condition(ctx)

    def _predict_changes(self, ctx: RunContext, power_old_w: float, power_w: float) -> None:
        """Each part's self-heating change at the supply change (`setpoint`): its C/W (the
        learned one, else the product's) times the change in the load's power per part."""
        c_per_w = ctx.product.self_heating_c_per_w
        for part in ctx.parts.alive():
            own = part.thermal.c_per_w_or(c_per_w)
            self._changes[part.socket] = (
                float("nan") if own is None else own * (power_w - power_old_w))

    @staticmethod
    def _power_each_w(ctx: RunContext) -> float:
        """The load's mean power per part now, W (the supply's reading)."""
        _, volts, amps = ctx.instruments.log_environment()
        return volts * amps / _load_size(ctx)

    def _decide_no_wait(self, ctx: RunContext) -> bool:
        """supply_change_no_wait: at a supply change at the same temperature, is every
        part's predicted self-heating change within the criterion (procedures.analysis
        .stability.change_settles)? Otherwise the step waits as without the setting."""
        st, prev = self.settings, self.place.previous
        if not st.supply_change_no_wait or prev is None or not self._changes:
            return False
        if prev.temperature_c != self.target.temperature_c or prev.supply_v == self.target.supply_v:
            return False
        tau_s = ctx.product.self_heating_tau_s
        settles = all(change_settles(c, tau_s, st.slope_c_per_min, st.band_c)
                      for c in self._changes.values())
        worst = max(abs(c) for c in self._changes.values())
        ctx.records.event(
            f"{self.condition}: supply change, predicted self-heating change up to {worst:.3f} C "
            + ("meets the criterion: measured at once" if settles
               else f"does not meet the criterion (band {st.band_c:g} C, slope "
               f"{st.slope_c_per_min:g} C/min): waits for stability"))
        return settles

    def _setup_fastest(self, ctx: RunContext) -> None:
        """The supply first (its self-heating step is part of the plan), then the plan."""
        chamber = ctx.instruments.chamber
        chamber.set_ramp_rate(ctx.procedure.chamber.ramp_c_per_min)
        alive = ctx.parts.alive()
        power_old_w = 0.0
        if self.place.previous is not None:  # the power each part drew before the change
            _, volts, amps = ctx.instruments.log_environment()
            power_old_w = volts * amps / _load_size(ctx)
        ctx.instruments.set_supply_voltage(self.target.supply_v)
        air_c, volts, amps = ctx.instruments.log_environment()
        self._mark_condition(ctx)
        power_w = volts * amps / _load_size(ctx)
        c_per_w = ctx.product.self_heating_c_per_w
        start: dict[int, tuple[float, float, float]] = {}
        for part in alive:
            reading_c = latest_reading_c(part, ctx.clock.now_s())
            die_c = part.thermal.die_now_c(ctx.wait.clock.now_s(), air_c)
            heat_now = heat_now_c(reading_c, die_c)
            part.thermal.observe(heat_now, power_old_w, c_per_w)
            own_c_per_w = part.thermal.c_per_w_or(c_per_w)
            heat_final = heat_after_change(heat_now, power_old_w, power_w, own_c_per_w)
            start[part.socket] = (reading_c, heat_now, heat_final)
            self._changes[part.socket] = heat_final - heat_now
        self._no_wait = self._decide_no_wait(ctx)
        if self._no_wait:  # the chamber stays at the target the last condition left it at
            if not chamber.is_running():
                chamber.run()
            return
        self._control = FastestController(chamber, control_settings(ctx, self))
        try:
            self._control.start(ctx.wait.clock.now_s(), air_c, chamber.read_setpoint(), start)
            if not chamber.is_running():
                chamber.run()
        except BaseException:
            leave_at_target(self._control)  # never left at an overshoot, even from setup
            raise

    def _mark_condition(self, ctx: RunContext) -> None:
        for part in ctx.parts.alive():
            part.conditions[self.condition] = ConditionResult(
                name=self.condition,
                temperature_c=self.target.temperature_c,
                supply_v=self.target.supply_v,
            )

    def _remember_dies(self, ctx: RunContext) -> None:
        """Each part's die as the controller estimates it now: the next condition starts
        from it (procedures.thermal.thermal_control.PartThermal)."""
        assert self._control is not None
        for part in ctx.parts.alive():
            state = self._control.die_lag_now(part.socket)
            if state is not None:
                part.thermal.remember_die(state[0], state[1], self._control.tau_of(part.socket))

    def _tick(self, ctx: RunContext, air_c: float) -> None:
        if self._control is None:
            return
        now = ctx.clock.now_s()
        readings = {p.socket: latest_reading_c(p, now) for p in ctx.parts.alive()}
        self._control.tick(ctx.wait.clock.now_s(), air_c, readings)

    def _air_arrived(self, air_c: float, band_c: float) -> bool:
        """The air at the target (setpoint), or at or past it on the way (fastest: the
        profile may hold the air beyond the target)."""
        error = air_c - self.target.temperature_c
        if self._control is None:
            return abs(error) <= band_c
        return abs(error) <= band_c or error * self._control.direction >= 0

    def main(self, ctx: RunContext) -> None:
        try:
            self._main(ctx)
        finally:
            control = getattr(self, "_control", None)
            if control is not None:
                leave_at_target(control)

    def _main(self, ctx: RunContext) -> None:
        start = ctx.wait.clock.now_s()
        if self._no_wait:
            self._measure_at_once(ctx, start)
            return
        # 1. the air first: a die that has not started to move is not stable
        self._wait_for_air(ctx, start)
        air_at = ctx.wait.clock.now_s()
        window_start = max(start, air_at - 0.0)
        # 2. every part on its own sensor
        stable_at, verdicts, volts, amps = self._wait_for_dies(ctx, start, window_start)
        if self._control is not None:
            self._control.finish()  # measure at the target, never at an overshoot
            self._remember_dies(ctx)
        end = ctx.wait.clock.now_s()
        amps_each = amps / _load_size(ctx)
        for part in ctx.parts.alive():
            self._record_stable(
                ctx, part, verdicts[part.socket], (start, stable_at[part.socket], end),
                volts, amps_each,
            )
        self.measured_from = {p.socket: len(p.record.measurements) for p in ctx.parts.alive()}
        if self.settings.overlap_measurement:
            ctx.records.event(
                f"{self.condition}: every die entering stability after {end - start:.0f} s "
                f"(criterion met over {self.settings.overlap_entry_s:g} s): measuring, the "
                f"{self.settings.window_s:g} s window is judged after the measurement")
        else:
            ctx.records.event(
                f"{self.condition}: all parts thermally stable after {end - start:.0f} s")

    def _measure_at_once(self, ctx: RunContext, start: float) -> None:
        """No wait (supply_change_no_wait): every part recorded as predicted to settle within
        the criterion; with overlap_measurement its window is judged after the measurement."""
        _, volts, amps = ctx.instruments.log_environment()
        amps_each = amps / _load_size(ctx)
        for part in ctx.parts.alive():
            reading = latest_reading_c(part, ctx.clock.now_s())
            v = StabilityVerdict(True, float("nan"), float("nan"), reading, 0.0)
            self._record_stable(ctx, part, v, (start, start, start), volts, amps_each)
        self.measured_from = {p.socket: len(p.record.measurements) for p in ctx.parts.alive()}

    def _wait_for_air(self, ctx: RunContext, start: float) -> None:
        """Until the chamber air arrives (ChamberSetpointNotReached past its timeout)."""
        st, cfg = self.settings, ctx.procedure.chamber
        while True:
            air, _, _ = ctx.instruments.log_environment()
            self._tick(ctx, air)
            if self._air_arrived(air, cfg.setpoint_band_c):
                return
            if ctx.wait.clock.now_s() - start > cfg.setpoint_timeout_s:
                raise ChamberSetpointNotReached(
                    f"chamber air at {air:.1f} C did not reach {self.target.temperature_c:g} C "
                    f"within {cfg.setpoint_timeout_s:g} s: check the chamber (door, compressor)",
                    instrument="chamber",
                )
            ctx.wait.sleep(st.check_interval_s)

    def _wait_for_dies(
        self, ctx: RunContext, start: float, window_start: float
    ) -> tuple[dict[int, float], dict[int, StabilityVerdict], float, float]:
        """Until every remaining part is stable (those that are not by the stability timeout
        dropped): when each became stable (station s), each part's last verdict, and the
        supply's last volts and amps."""
        st = self.settings
        stable_at: dict[int, float] = {}
        verdicts: dict[int, StabilityVerdict] = {}
        while True:
            ctx.wait.sleep(st.check_interval_s)
            air, volts, amps = ctx.instruments.log_environment()
            self._tick(ctx, air)
            handover = self._may_hand_over(ctx)
            for part in ctx.parts.alive():
                if part.socket in stable_at:
                    continue
                v = verdicts[part.socket] = self._judge(ctx, part, window_start)
                if v.stable and handover:
                    stable_at[part.socket] = ctx.wait.clock.now_s()
            alive = ctx.parts.alive()
            if all(p.socket in stable_at for p in alive):
                return stable_at, verdicts, volts, amps
            if ctx.wait.clock.now_s() - start > st.stability_timeout_s:
                for part in alive:
                    if part.socket not in stable_at:
                        self._drop_unstable(ctx, part, verdicts.get(part.socket))
                ctx.parts.require()
                return stable_at, verdicts, volts, amps

    def _may_hand_over(self, ctx: RunContext) -> bool:
        """overlap_measurement under `fastest`: not before the planned profile is at the
        target for good (measuring ends the profile at once: a die entering stability while
        the profile still shapes it would be moved by that)."""
        if not self.settings.overlap_measurement or self._control is None:
            return True
        return self._control.at_target_for_good(ctx.wait.clock.now_s())

    def _judge(self, ctx: RunContext, part: Any, window_start: float) -> StabilityVerdict:
        st = self.settings
        assert part.stream is not None
        f0 = part.stream.fixture_time(window_start)
        # only the last window is judged: read no more (the run's raw file holds it)
        recent = part.stream.fixture_time(ctx.clock.now_s()) - 2.0 * st.window_s
        data = part.stream.window(max(f0, recent), np.inf)
        # overlap_measurement: a shorter span first, the full window after the measurement
        span_s = st.overlap_entry_s if st.overlap_measurement else st.window_s
        return judge_stability(
            data["time_s"],
            data["temp_c"],
            span_s,
            st.slope_c_per_min,
            st.band_c,
            self.target.temperature_c,
            st.target_tolerance_c,
        )

    def _drop_unstable(self, ctx: RunContext, part: Any, last: StabilityVerdict | None) -> None:
        st = self.settings
        slope = last.slope_c_per_min if last else float("nan")
        band = last.band_c if last else float("nan")
        ctx.parts.drop(
            part,
            Verdict.ERROR,
            (
                "die temperature not stable within "
                f"{st.stability_timeout_s:g} s at "
                f"{self.condition} (slope {slope:.3f} C/min, band {band:.3f} C): "
                "check the part's seating and the chamber; or relax stability "
                "in the procedure"
            ),
        )

    def _record_stable(
        self,
        ctx: RunContext,
        part: Any,
        v: StabilityVerdict,
        times: tuple[float, float, float],
        volts: float,
        amps_each: float,
    ) -> None:
        """A stable part's condition result, stabilise segment and stability analysis;
        `times`: the condition set, the part stable, measurement start (station s)."""
        st = self.settings
        start, stable_s, end = times
        res = part.conditions[self.condition]
        res.stable = True
        res.time_to_stability_s = stable_s - start
        res.die_temperature_c = v.mean_c  # until the measurements give their own mean
        res.supply_measured_v = volts
        res.supply_current_a = amps_each
        assert part.stream is not None
        ctx.records.segment(
            part,
            "stabilise",
            0,
            part.stream.fixture_time(start),
            part.stream.fixture_time(stable_s),
            temp_setpoint_c=self.target.temperature_c,
            supply_v=self.target.supply_v,
        )
        control = {} if self._control is None else {
            **self._control.summary(part.socket), "self_heating_c_per_w": part.thermal.c_per_w
        }
        part.record.analysis.stability[self.condition] = StabilityResults(
            window_s=st.window_s,
            max_rate_c_per_min=st.slope_c_per_min,
            band_c=st.band_c,
            tolerance_c=st.target_tolerance_c,
            time_to_stability_s=res.time_to_stability_s,
            stable=True,
            slope_c_per_min=v.slope_c_per_min,
            measured_band_c=v.band_c,
            die_temperature_c=v.mean_c,
            stable_at_station_s=stable_s,
            stable_at_fixture_s=part.stream.fixture_time(stable_s),
            condition_set_station_s=start,
            measurement_start_station_s=end,
            judged=self._judged(),
            entry_s=st.overlap_entry_s if st.overlap_measurement else None,
            predicted_change_c=self._changes.get(part.socket) if self._no_wait else None,
            **control,
        )

    def _judged(self) -> str:
        """How this condition's window is judged (StabilityResults.judged)."""
        if self.settings.overlap_measurement:
            return "after"
        return "predicted" if self._no_wait else "before"

    def after_condition(self, body: list[StepType[Any]]) -> list[StepType[Any]]:
        """overlap_measurement: the window judged after the condition's measurement steps
        (those after this one in the condition's pass), which run again for a part whose
        window fails (procedures.steps.thermal_after)."""
        if not self.settings.overlap_measurement:
            return []
        return [JudgedAfter(self, body[body.index(self) + 1:])]
