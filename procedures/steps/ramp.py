"""Ramp calibration: bias and scale measured while the chamber heats and then cools the parts.

Instead of waiting at stable temperatures (the `thermal` step at each condition), the chamber
ramps the dies up across the procedure's temperature span and back down (Niu et al. 2013),
and meanwhile the rate table cycles through the rate set without stopping, the supply
alternating between the procedure's levels each sweep. Every plateau is kept with the part's
mean output, its own sensor's temperature and (afterwards) the temperature's rate of change;
procedures/steps/ramp_record.py fits them (procedures/analysis/ramp_fit.py) into the same
calibration the `fit` step produces, so `program` and `verify` follow unchanged.

The chamber is driven at its ramp rate towards an overshoot (the hottest setpoint the chamber
and the product allow, `max_setpoint_c`) and turned when every die's predicted peak reaches
the span's top (procedures/thermal/ramp_turn.py), then driven down towards `min_setpoint_c`
and turned back to the end setpoint when every die's predicted trough reaches the span's
bottom. The dies therefore cover the span both ways with the highest rates the chamber
allows, and the step ends with the chamber going back to `end_setpoint_c`.

With `stop_method` set, the table performs the article's stop method in place of plateaus
near the top (the dies at their peak) and near the bottom (after the static dwell), and each
record's scale is judged against the fitted scale law there (procedures/steps/ramp_stop.py).
"""

from __future__ import annotations

import logging
from functools import partial
from typing import Any

import numpy as np
from pydantic import Field

from common.bounded import MAX_ACCEL_DPS2, MAX_LIST, ONE_HOUR_S
from drivers.errors import ChamberSetpointNotReached, InstrumentError
from procedures.analysis.allan import NoiseModel
from procedures.runtime.results import RampResults
from procedures.runtime.run_context import RunContext
from procedures.steps.bias import NOISE
from procedures.steps.fit import COEFF_UNITS
from procedures.steps.ramp_record import RAW, PlateauLog, fit_and_record
from procedures.steps.ramp_static import record_static_noise, static_dwell, wander_model
from procedures.steps.ramp_stop import CONSISTENCY, RampStopSettings, StopAtEnd, judge, run_stop
from procedures.steps.registry import Declared, Provided, StepSettings, StepType
from procedures.steps.sweep import measure_plateau
from procedures.steps.thermal_fastest import latest_reading_c
from procedures.thermal.ramp_turn import (
    RampModel,
    RampState,
    extreme_after_turn,
    ramped_setpoint,
)
from procedures.units import Rate, Seconds

log = logging.getLogger(__name__)

# the static dwell's condition label: where it is, the span's bottom (as the stop record after
# it). Not a temperature-and-supply name: the supply applied then depends on how many sweeps
# the ramp took, which varies from load to load, and a measurement's condition must not (the
# line's history groups by it).
STATIC_CONDITION = "ramp_bottom"
RATE_WINDOW_S = 20.0  # a die's rate for the turn: a line over its last 20 s


# the ramp's time left, as it learns its length (measured in lockstep on eol-ramp, SIM-7001/2
# and config/sim/eight_sockets.yaml: heating 340-347 s, cooling with the top's stop 563-593 s,
# the bottom's settling, dwell, stop and fit 265-272 s; benchmarks/bench_ramp_phases.py):
# the cooling half takes longer than
# the heating half, the dies' lag reaching further from the chamber's turn
COOL_PER_HEAT = 1.65
AFTER_COOLING_S = 270.0

class RampSettings(StepSettings):
    rates_dps: list[Rate] = Field(
        min_length=2, max_length=MAX_LIST,
        description="rate set the table cycles through while the dies move, deg/s (both "
        "signs)",
    )
    plateau_dwell_s: Seconds = Field(6.0, gt=0, description="averaging time on each plateau")
    settle_s: float = Field(0.5, ge=0, le=ONE_HOUR_S, description="wait after at-rate")
    accel_dps2: float = Field(
        200.0, gt=0, le=MAX_ACCEL_DPS2, description="table acceleration, deg/s^2"
    )
    at_rate_timeout_s: Seconds = Field(30.0, gt=0, description="time allowed to reach a rate")
    max_setpoint_c: float | None = Field(
        None, ge=-100, le=200, description="hottest setpoint while heating (the overshoot); "
        "default: the product's max_part_temperature_c within the chamber's limits",
    )
    min_setpoint_c: float | None = Field(
        None, ge=-100, le=200, description="coldest setpoint while cooling; default: the "
        "product's min_part_temperature_c within the chamber's limits",
    )
    end_setpoint_c: float | None = Field(
        None, ge=-100, le=200,
        description="setpoint after the ramp; default: the chamber's safe_temp_c",
    )
    max_element_tau_s: float | None = Field(
        None, gt=0, le=3600, description="a part whose element lags its sensor beyond this "
        "(95 % confident) is refused; default: the product's thermal_typical element_tau_s "
        "+ 4 sigma (else 60 s)",
    )
    end_rate_c_per_min: float = Field(
        0.5, gt=0, le=100, description="after the turn at the bottom the table goes on "
        "cycling until every die's rate is within this (verify then sees a die near rest)",
    )
    skip_s: Seconds = Field(
        30.0, ge=0, description="plateaus this soon after the step starts are not fitted "
        "(the die's self-heating after power-on bends its temperature fastest)",
    )
    max_duration_s: Seconds = Field(
        3600.0, gt=0, description="the ramp must be done within this (else ERROR)"
    )
    static_s: float = Field(
        60.0, ge=0, le=ONE_HOUR_S, description="static dwell while the dies come to rest "
        "after the turn at the bottom (table at rest; it takes the place of plateaus): "
        "noise_arw_deg_per_sqrt_h and bias_instability_deg_per_h from its Allan "
        "deviation; 0: none (noise not measured)",
    )
    static_below_c_per_min: float = Field(
        1.0, gt=0, le=100, description="the static dwell starts once every die is slower "
        "than this after the turn at the bottom (at least end_rate_c_per_min)",
    )
    stop_method: RampStopSettings | None = Field(
        None, description="the article's stop method at the ends of the span, in place of "
        "plateaus (procedures/steps/ramp_stop.py): {stop_angle_deg: 90, move_time_s: 3.5, "
        "static_s: 5, bias_window_s: 3, moves_per_direction: 1, ends: [top, bottom], "
        "move_timeout_s: 60}; at the top once no die heats faster than "
        "static_below_c_per_min, at the bottom after the static dwell once every die is "
        "that slow; each record's scale against the fitted law there "
        "(stop_table_consistency@ramp_<end>); none: not run",
    )


def _typical_bounds(product: Any, limit: float | None) -> tuple[float, float, float, float]:
    """(refusal limit, the lag assumed where the data cannot tell it, hysteresis width,
    the typical lag) from the product's thermal_typical."""
    typ = product.thermal_typical
    if typ is None:
        return (limit or 60.0), (limit or 60.0), 1.0, 0.0
    tau, sigma = typ.element_tau_s, typ.element_tau_sigma_s
    return (limit or tau + 4 * sigma), tau + 3 * sigma, typ.hysteresis_width_c, tau


class RampCalibration(StepType[RampSettings]):
    """Bias and scale over a heating-and-cooling chamber ramp, the rate table cycling and
    the supply alternating; fitted with the die's rate of change for the gradient and the
    lag (per part), into the first-order calibration."""

    type_name = "ramp_calibration"
    Settings = RampSettings
    uses_table = True
    provides = frozenset({Provided.FIT})
    Results = RampResults

    @classmethod
    def measurements(cls, settings: Any) -> list[Declared]:
        coeffs = [Declared(name, units, "first-order coefficient (ramp)")
                  for name, units in COEFF_UNITS.items()]
        own_h = Declared("hysteresis_dps", "deg/s", "the part's own hysteresis (the ramp's "
                         "heating and cooling halves)", informational=True, optional=True)
        stop = (CONSISTENCY,) if settings.stop_method is not None else ()
        return [*coeffs, own_h, *RAW, *(NOISE if settings.static_s > 0 else ()), *stop]

    def stop_judgements(self) -> int:
        """How many stop-vs-fit judgements the step makes on one part (one per end)."""
        sm = self.settings.stop_method
        return 0 if sm is None else len(sm.ends)

    def estimate_s(self, ctx: RunContext) -> float:
        """Before it starts (ctx.progress.revise corrects it at the turns, from the time the
        heating half took: COOL_PER_HEAT, AFTER_COOLING_S)."""
        # measured on the simulated bench: 1150 s for 20 C at 5 C/min (the dies' lag rules)
        span = self._span(ctx)
        return 60.0 * (span[1] - span[0]) * 4.8 / max(ctx.procedure.chamber.ramp_c_per_min, 1.0)

    def _span(self, ctx: RunContext) -> tuple[float, float]:
        temps = ctx.procedure.conditions.temperatures_c
        return float(min(temps)), float(max(temps))

    def _setpoint_limits(self, ctx: RunContext) -> tuple[float, float]:
        st, product = self.settings, ctx.product
        low, high = ctx.instruments.chamber.setpoint_limits()
        if product.max_part_temperature_c is not None:
            high = min(high, product.max_part_temperature_c)
        if product.min_part_temperature_c is not None:
            low = max(low, product.min_part_temperature_c)
        if st.max_setpoint_c is not None:
            high = min(high, st.max_setpoint_c)
        if st.min_setpoint_c is not None:
            low = max(low, st.min_setpoint_c)
        return low, high

    def _end_c(self, ctx: RunContext) -> float:
        end_c = self.settings.end_setpoint_c
        return ctx.procedure.chamber.safe_temp_c if end_c is None else end_c

    def main(self, ctx: RunContext) -> None:
        ctx.instruments.need_table().enable()
        logs = {p.socket: PlateauLog() for p in ctx.parts.alive()}
        self._end_turn: float | None = None
        self._stops: dict[int, list[StopAtEnd]] = {}
        self._stops_done: set[str] = set()
        self._noise: dict[int, NoiseModel] = {}  # each part's, from the static dwell
        self._own_bi: dict[int, float] = {}  # the dwell's bias instability (0: unresolved)
        try:
            start = self._start_chamber(ctx)
            self._static_done = self.settings.static_s <= 0
            turned_at = self._ramp(ctx, logs, start)
        except BaseException:
            self._leave_at_end(ctx)  # never left heading for an overshoot
            raise
        ctx.progress.set_phase("fitting")
        low, high = self._span(ctx)
        bounds = _typical_bounds(ctx.product, self.settings.max_element_tau_s)
        for part in ctx.parts.alive():
            given = dict(turned_at_station_s=turned_at, end_turn_station_s=self._end_turn)
            results = RampResults(low_c=low, high_c=high, max_element_tau_s=bounds[0],
                                  supplies_v=list(ctx.procedure.conditions.supplies_v),
                                  **{k: v for k, v in given.items() if v is not None})
            ctx.parts.per_part(part, partial(
                self._record_part, ctx, log=logs[part.socket], results=results,
                bounds=bounds))

    def _record_part(self, ctx: RunContext, part: Any, **kwargs: Any) -> None:
        """One part's fit, then its stop-method records against the fit."""
        fit = fit_and_record(ctx, part, own_bi_dps=self._own_bi.get(part.socket, 0.0), **kwargs)
        judge(ctx, part, fit, self._stops.get(part.socket, []), self._noise.get(part.socket))

    def _start_chamber(self, ctx: RunContext) -> float:
        """The chamber heading for the overshoot at its ramp rate; when (station s)."""
        chamber = ctx.instruments.chamber
        high_sp = self._setpoint_limits(ctx)[1]
        start = ctx.wait.clock.now_s()
        self._turn = (start, chamber.read_temperature(), high_sp)  # since, from, towards
        chamber.set_ramp_rate(ctx.procedure.chamber.ramp_c_per_min)
        chamber.set_setpoint(high_sp)
        if not chamber.is_running():
            chamber.run()
        return start

    def _static(self, ctx: RunContext) -> None:
        """The static dwell (procedures/steps/ramp_static.py) once the dies are slow enough
        that they come to rest no sooner than it ends: each part's noise from it."""
        st = self.settings
        self._static_done = True
        ctx.progress.set_phase("static")
        t0, t1 = static_dwell(ctx, st.static_s, st.accel_dps2, st.at_rate_timeout_s)
        label = STATIC_CONDITION

        def noise_of(part: Any) -> None:
            allan = record_static_noise(ctx, part, t0, t1, label)
            if allan is not None:
                self._noise[part.socket] = wander_model(allan)
                self._own_bi[part.socket] = allan.noise.model.bias_instability_dps

        ctx.parts.each(noise_of)

    def _ramp(self, ctx: RunContext, logs: dict[int, PlateauLog], start: float
              ) -> float | None:
        """Heat, turn, cool, turn to the end setpoint, until the dies are near rest; the
        table cycling and the supply alternating all along; returns when the chamber
        turned from heating to cooling (station s)."""
        st = self.settings
        low_sp = self._setpoint_limits(ctx)[0]
        phase, turned_at, sweep = "heating", None, 0
        supplies = list(ctx.procedure.conditions.supplies_v)
        while phase != "done":
            ctx.instruments.set_supply_voltage(supplies[sweep % len(supplies)])
            volts = ctx.instruments.log_supply()[0]
            for rate in st.rates_dps:
                ctx.progress.set_phase(phase)
                plateau = measure_plateau(ctx, rate, st.plateau_dwell_s, st.settle_s,
                                          st.accel_dps2, st.at_rate_timeout_s,
                                          sleep_through_change=True)
                if plateau.t0_s - start >= st.skip_s:
                    for part in ctx.parts.alive():
                        ctx.parts.per_part(part, partial(
                            logs[part.socket].add, ctx, p=plateau, supply_v=volts,
                            heating=phase == "heating", dwell_s=st.plateau_dwell_s))
                phase = self._next_phase(ctx, phase, low_sp)
                if phase == "cooling" and turned_at is None:
                    turned_at = ctx.wait.clock.now_s()
                    ctx.progress.revise(COOL_PER_HEAT * (turned_at - start) + AFTER_COOLING_S)
                if phase == "done":
                    break
            sweep += 1
            if ctx.wait.clock.now_s() - start > st.max_duration_s:
                raise ChamberSetpointNotReached(
                    f"the ramp did not cover {self._span(ctx)} C both ways within "
                    f"{st.max_duration_s:g} s: check the chamber, or widen max_setpoint_c / "
                    "min_setpoint_c", instrument="chamber")
        table = ctx.instruments.need_table()
        table.set_rate(0.0, st.accel_dps2)
        table.wait_at_rate(st.at_rate_timeout_s)
        return turned_at

    def _leave_at_end(self, ctx: RunContext) -> None:
        """The chamber to the end setpoint on any way out of the ramp; a failure here is
        logged, not raised over the error that ended the step (the safe state follows)."""
        try:
            ctx.instruments.chamber.set_setpoint(self._end_c(ctx))
        except InstrumentError as exc:
            log.error("could not send the chamber to %.1f C: %s", self._end_c(ctx), exc)

    def _stop_due(self, ctx: RunContext, phase: str) -> None:
        """The stop-method record at an end when it is due: at the top once no die heats
        faster than static_below_c_per_min, at the bottom after the static dwell once every
        die is that slow."""
        sm, st = self.settings.stop_method, self.settings
        end = {"cooling": "top", "settling": "bottom"}.get(phase)
        if sm is None or end is None or end not in sm.ends or end in self._stops_done:
            return
        now, limit = ctx.wait.clock.now_s(), st.static_below_c_per_min / 60.0
        rates = [_die_now(p, now)[1] for p in ctx.parts.alive()]
        slow = (all(r <= limit for r in rates) if end == "top"
                else self._static_done and all(abs(r) <= limit for r in rates))
        if slow:
            self._stops_done.add(end)
            ctx.progress.set_phase(f"stop_{end}")
            run_stop(ctx, sm, end, self._stops, self._noise)

    def _next_phase(self, ctx: RunContext, phase: str, low_sp: float) -> str:
        if phase == "heating" and self._should_turn(ctx, True, low_sp):
            self._set_towards(ctx, low_sp)
            return "cooling"
        if phase == "cooling" and self._should_turn(ctx, False, self._end_c(ctx)):
            self._set_towards(ctx, self._end_c(ctx))
            self._end_turn = ctx.wait.clock.now_s()
            ctx.progress.revise(AFTER_COOLING_S)
            return "settling"
        st = self.settings
        if phase == "settling" and not self._static_done and self._dies_at_rest(
                ctx, max(st.static_below_c_per_min / st.end_rate_c_per_min, 1.0)):
            self._static(ctx)
        self._stop_due(ctx, phase)
        if phase == "settling" and self._static_done and self._dies_at_rest(ctx):
            return "done"
        return phase

    def _set_towards(self, ctx: RunContext, target_c: float) -> None:
        now = ctx.wait.clock.now_s()
        self._turn = (now, self._setpoint_now(ctx, now), target_c)
        ctx.instruments.chamber.set_setpoint(target_c)

    def _setpoint_now(self, ctx: RunContext, now: float) -> float:
        since, start_c, target_c = self._turn
        return ramped_setpoint(start_c, target_c, ctx.procedure.chamber.ramp_c_per_min,
                               now - since)

    def _dies_at_rest(self, ctx: RunContext, factor: float = 1.0) -> bool:
        """Every die's rate within `factor` x end_rate_c_per_min."""
        now = ctx.wait.clock.now_s()
        limit = factor * self.settings.end_rate_c_per_min / 60.0
        return all(abs(_die_now(p, now)[1]) <= limit for p in ctx.parts.alive())

    def _should_turn(self, ctx: RunContext, heating: bool, towards_c: float) -> bool:
        """Heating: every die's predicted peak, were the setpoint to turn towards
        `towards_c` now, at the span's top or beyond; cooling: every die's predicted trough
        at its bottom or below (each die's now and rate from its own sensor)."""
        air_c, _, _ = ctx.instruments.log_environment()
        now = ctx.wait.clock.now_s()
        low, high = self._span(ctx)
        cfg = ctx.procedure.chamber
        model = RampModel(cfg.ramp_c_per_min, cfg.air_tau_s, ctx.product.die_tau_s)
        sp = self._setpoint_now(ctx, now)
        for part in ctx.parts.alive():
            die_c, rate = _die_now(part, now)
            if not np.isfinite(die_c):
                continue
            state = RampState(sp, air_c, die_c, rate)
            if heating and (rate <= 0 or extreme_after_turn(state, towards_c, model) < high):
                return False
            if not heating and (rate >= 0 or extreme_after_turn(state, towards_c, model) > low):
                return False
        return True


def _die_now(part: Any, station_now_s: float) -> tuple[float, float]:
    """A part's die temperature now and its rate (C/s), a line over its last samples."""
    if part.stream is None:
        return float("nan"), 0.0
    end = part.stream.fixture_time(station_now_s)
    data = part.stream.window(end - RATE_WINDOW_S, np.inf)
    t, y = data["time_s"], data["temp_c"]
    if t.size < 10:
        return latest_reading_c(part, station_now_s), 0.0
    slope, icpt = np.polyfit(t - t[-1], y, 1)
    return float(icpt), float(slope)
