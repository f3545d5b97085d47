"""Thermal stabilisation, judged on each part's own die temperature sensor.

The chamber air reaching its setpoint says nothing about the die, which lags by minutes.
The step first waits for the air (so a die that has not started moving is not mistaken for a
stable one), then judges every part on its own sensor: over the last `window_s`, the slope of
a straight-line fit and the peak-to-peak of one-second means must both be small. The window
must lie entirely after the condition was set. Measurement starts when every remaining part
is stable; a part that never gets there is dropped when the stability timeout runs out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from pydantic import Field

from common.bounded import ONE_HOUR_S
from drivers.errors import ChamberSetpointNotReached
from procedures.runtime.record import Verdict
from procedures.runtime.results import StabilityResults
from procedures.runtime.run_context import RunContext
from procedures.runtime.run_parts import ConditionResult
from procedures.steps.registry import StepSettings, StepType
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


@dataclass(frozen=True)
class StabilityVerdict:
    stable: bool
    slope_c_per_min: float
    band_c: float
    mean_c: float
    span_s: float


def judge_stability(
    time_s: NDArray[np.float64],
    temp_c: NDArray[np.float64],
    window_s: float,
    slope_c_per_min: float,
    band_c: float,
    target_c: float | None = None,
    tolerance_c: float | None = None,
) -> StabilityVerdict:
    """Is the last `window_s` of a die temperature record stable? (needs a full window)."""
    if time_s.size < 3 or time_s[-1] - time_s[0] < window_s * 0.98:
        return StabilityVerdict(
            False,
            float("nan"),
            float("nan"),
            float("nan"),
            float(time_s[-1] - time_s[0]) if time_s.size else 0.0,
        )
    sel = time_s >= time_s[-1] - window_s
    t, y = time_s[sel], temp_c[sel]
    slope = float(np.polyfit(t - t[0], y, 1)[0]) * 60.0
    # peak-to-peak of 1 s means: the band is about drift, not sensor noise
    bins = np.floor(t - t[0]).astype(np.int64)
    counts = np.bincount(bins)
    sums = np.bincount(bins, weights=y)
    means = sums[counts > 0] / counts[counts > 0]
    band = float(np.ptp(means))
    mean = float(y.mean())
    ok = abs(slope) <= slope_c_per_min and band <= band_c
    if ok and target_c is not None and tolerance_c is not None:
        ok = abs(mean - target_c) <= tolerance_c
    return StabilityVerdict(ok, slope, band, mean, float(t[-1] - t[0]))


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


def _heating_c(product: Any, supply_v: float) -> float:
    """A typical part's self-heating at `supply_v` (0 when the product gives no C/W)."""
    if not product.self_heating_c_per_w:
        return 0.0
    return steady_die_c(0.0, supply_v, product.typical_current_a, product.self_heating_c_per_w)


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
        if ctx.procedure.chamber.strategy == "fastest":
            self._setup_fastest(ctx)
            return
        chamber, cfg = ctx.instruments.chamber, ctx.procedure.chamber
        if abs(chamber.read_setpoint() - self.target.temperature_c) > 0.05:
            chamber.set_ramp_rate(cfg.ramp_c_per_min)
            chamber.set_setpoint(self.target.temperature_c)
        if not chamber.is_running():
            chamber.run()
        ctx.instruments.set_supply_voltage(self.target.supply_v)
        self._mark_condition(ctx)

    def _setup_fastest(self, ctx: RunContext) -> None:
        """The supply first (its self-heating step is part of the plan), then the plan."""
        chamber = ctx.instruments.chamber
        chamber.set_ramp_rate(ctx.procedure.chamber.ramp_c_per_min)
        alive = ctx.parts.alive()
        power_old_w = 0.0
        if self.place.previous is not None:  # the power each part drew before the change
            _, volts, amps = ctx.instruments.log_environment()
            power_old_w = volts * amps / max(len(alive), 1)
        ctx.instruments.set_supply_voltage(self.target.supply_v)
        air_c, volts, amps = ctx.instruments.log_environment()
        self._mark_condition(ctx)
        power_w = volts * amps / max(len(alive), 1)
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
        amps_each = amps / max(len(ctx.parts.alive()), 1)
        for part in ctx.parts.alive():
            self._record_stable(
                ctx, part, verdicts[part.socket], (start, stable_at[part.socket], end),
                volts, amps_each,
            )
        ctx.records.event(f"{self.condition}: all parts thermally stable after {end - start:.0f} s")

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
            for part in ctx.parts.alive():
                if part.socket in stable_at:
                    continue
                v = verdicts[part.socket] = self._judge(ctx, part, window_start)
                if v.stable:
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

    def _judge(self, ctx: RunContext, part: Any, window_start: float) -> StabilityVerdict:
        st = self.settings
        assert part.stream is not None
        f0 = part.stream.fixture_time(window_start)
        # only the last window is judged: read no more (the run's raw file holds it)
        recent = part.stream.fixture_time(ctx.clock.now_s()) - 2.0 * st.window_s
        data = part.stream.window(max(f0, recent), np.inf)
        return judge_stability(
            data["time_s"],
            data["temp_c"],
            st.window_s,
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
            **control,
        )
