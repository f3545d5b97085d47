"""The `fastest` thermal strategy at run time: plan, command, learn, re-plan.

At a condition's start the controller plans a setpoint profile for every part's die, each with
its own lag and self-heating, and commands it: the sooner of the linear programme's profile
(procedures/thermal/chamber_profile.py) and a bounded overshoot held, then the target
(procedures/thermal/chamber_strategy.py). Every check it advances its estimate of the chamber's
ramped setpoint, records the air and each part's own reading, and every
`replan_interval_s` learns each die's lag from those readings and plans again from where
things are. The self-heating step of a supply change is predicted from the reading's excess
over the air and the product's C/W times the change in measured power (or scaled by the
power ratio). `finish` commands the target: the chamber is never left at an overshoot.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from procedures.thermal.chamber_profile import ProfilePlan, plan_lp_profile
from procedures.thermal.chamber_strategy import (
    Criterion,
    DieState,
    SetpointPlan,
    ThermalLimits,
    ThermalModel,
    learn_die_tau_s,
    plan_profile,
)

log = logging.getLogger(__name__)

SETPOINT_RESOLUTION_C = 0.1  # the chamber's setpoint register holds tenths
MIN_LEARN_C2 = 100.0  # sum of (air - die)^2 over the readings before a lag is learned
TAU_RANGE = 3.0  # a learned lag stays within 1/3..3 times the product's value
MIN_HEAT_STEP_C = 0.1  # a self-heating step smaller than this is not learned within a condition
HEAT_PRIOR_WEIGHT = 3.0  # the predicted self-heating weighs as much as 3 settled readings
C_PER_W_RANGE = 3.0  # a part's learned C/W stays within 1/3..3 times the product's value


def die_lag_c(
    time_s: np.ndarray, air_c: np.ndarray, start_c: float, tau_s: float
) -> np.ndarray:
    """The die (without its self-heating) lagging the air from `start_c`, at the readings'
    times (the air linear between them)."""
    die = np.empty_like(air_c)
    die[0] = start_c
    for i in range(1, time_s.size):
        k = 1.0 - math.exp(-(time_s[i] - time_s[i - 1]) / tau_s)
        die[i] = die[i - 1] + (0.5 * (air_c[i] + air_c[i - 1]) - die[i - 1]) * k
    return die


def learn_heat_final_c(
    elapsed_s: np.ndarray, heat_c: np.ndarray, heat0_c: float, prior_c: float,
    heat_tau_s: float, prior_weight: float = HEAT_PRIOR_WEIGHT,
) -> float:
    """The self-heating a part tends to, from its readings less its die's lag (`heat_c`):
    least squares on heat = final + (heat0 - final) exp(-t / tau), pulled towards the
    prediction `prior_c` with the weight of `prior_weight` readings; the prediction alone
    while the heating has hardly moved. Kept within the step's size of the prediction."""
    decay = np.exp(-np.asarray(elapsed_s) / heat_tau_s)
    x = 1.0 - decay
    y = np.asarray(heat_c) - heat0_c * decay
    ok = np.isfinite(y)
    learned = (float(x[ok] @ y[ok]) + prior_weight * prior_c) / (
        float(x[ok] @ x[ok]) + prior_weight
    )
    step = max(abs(prior_c - heat0_c), MIN_HEAT_STEP_C)
    return min(max(learned, prior_c - step), prior_c + step)


class SetpointChamber(Protocol):
    def set_setpoint(self, temp_c: float) -> None: ...


@dataclass(frozen=True)
class ControlSettings:
    """Everything the controller needs from the procedure, the product and the chamber."""

    target_c: float
    criterion: Criterion
    model: ThermalModel
    limits: ThermalLimits
    die_tau_prior_s: float
    heat_tau_s: float
    replan_interval_s: float


@dataclass
class _Part:
    die0_c: float  # reading at the start
    heat0_c: float  # self-heating part of it at the start
    heat_final_c: float
    tau_s: float
    time_s: list[float] = field(default_factory=list)
    reading_c: list[float] = field(default_factory=list)


def heat_now_c(reading_c: float, die_c: float) -> float:
    """The self-heating in a part's reading at a condition's start: its excess over its die
    (the air, or where the die was at the last condition's end gone on towards the air:
    `PartThermal.die_now_c`), with any constant offset of the part's sensor, which stays."""
    return reading_c - die_c


def heat_after_change(
    heat_now: float, power_old_w: float, power_new_w: float, c_per_w: float | None,
) -> float:
    """The self-heating a part tends to at the new supply: the present heating changed by the
    product's C/W times the change in the power it draws (at power-on, `power_old_w` 0: the
    C/W times the power); without C/W, the present heating scaled by the power ratio."""
    if c_per_w is None:
        return heat_now * power_new_w / power_old_w if power_old_w > 0 else heat_now
    if power_old_w <= 0:
        return c_per_w * max(power_new_w, 0.0)
    return heat_now + c_per_w * (power_new_w - power_old_w)


@dataclass
class PartThermal:
    """What the `fastest` strategy learned of one part from its own sensor, carried from
    condition to condition.

    - Its die without the self-heating (`die_lag_c` at station time `die_lag_at_s`, lag
      `tau_s`) at the end of a condition's wait: through the measurement that follows, the air
      holds at the target and the die goes on towards it, so the next condition starts from
      where the die really is (a die judged stable may still creep), not from the air.
    - Its own C/W: at the first condition (power-on) the part's excess over its die is its
      sensor's offset and what it had heated so far (`excess_at_power_on_c`); at each later
      condition's start the excess less that is its heating at the power it drew, per watt of
      the load's mean power per part (a part drawing more current heats more per mean watt).
      The sensor's offset cancels.
    """

    excess_at_power_on_c: float | None = None
    c_per_w: float | None = None  # learned; None until a condition has been measured powered
    die_lag_c: float | None = None
    die_lag_at_s: float = 0.0
    tau_s: float = 0.0

    def die_now_c(self, now_s: float, air_c: float) -> float:
        """The die (without self-heating) now: where it was, gone on towards the air."""
        if self.die_lag_c is None or not self.tau_s > 0 or not math.isfinite(self.die_lag_c):
            return air_c
        decay = math.exp(-max(now_s - self.die_lag_at_s, 0.0) / self.tau_s)
        return air_c + (self.die_lag_c - air_c) * decay

    def remember_die(self, die_lag_c: float | None, at_s: float, tau_s: float) -> None:
        if die_lag_c is not None and math.isfinite(die_lag_c):
            self.die_lag_c, self.die_lag_at_s, self.tau_s = die_lag_c, at_s, tau_s

    def observe(self, excess_c: float, power_w: float, product_c_per_w: float | None) -> None:
        """The excess over the die at a condition's start, the power drawn before it."""
        if not math.isfinite(excess_c):
            return
        if self.excess_at_power_on_c is None or power_w <= 0:
            self.excess_at_power_on_c = excess_c
            return
        learned = (excess_c - self.excess_at_power_on_c) / power_w
        if product_c_per_w is not None and product_c_per_w > 0:  # a sensor fault is not heating
            low, high = product_c_per_w / C_PER_W_RANGE, product_c_per_w * C_PER_W_RANGE
            learned = min(max(learned, low), high)
        self.c_per_w = learned

    def c_per_w_or(self, product_c_per_w: float | None) -> float | None:
        return self.c_per_w if self.c_per_w is not None else product_c_per_w


class FastestController:
    """Drives the chamber through planned profiles for one condition."""

    def __init__(self, chamber: SetpointChamber, settings: ControlSettings) -> None:
        self.chamber = chamber
        self.cfg = settings
        self.parts: dict[int, _Part] = {}
        self.air_time_s: list[float] = []
        self.air_c: list[float] = []
        self.plan: SetpointPlan | ProfilePlan | None = None
        self.first_plan: SetpointPlan | ProfilePlan | None = None
        self.plan_at_s = 0.0
        self.ramped_c = settings.target_c
        self.commanded_c: float | None = None
        self.last_s = 0.0
        self.replans = 0
        self.direction = 1.0

    # ------------------------------------------------------------ start, tick, finish

    def start(
        self, now_s: float, air_c: float, setpoint_c: float,
        parts: dict[int, tuple[float, float, float]],
    ) -> None:
        """Plan and command the first setpoint. `parts`: socket -> (reading, self-heating
        now, self-heating at the new supply) C; the rest of the reading is the die's lag."""
        self.ramped_c = setpoint_c if abs(air_c - setpoint_c) < 1.0 else air_c
        self.direction = 1.0 if self.cfg.target_c >= air_c else -1.0  # the air's way to go
        for socket, (reading_c, heat0, heat_final_c) in parts.items():
            self.parts[socket] = _Part(reading_c, heat0, heat_final_c, self.cfg.die_tau_prior_s)
        self.last_s = now_s
        self._observe(now_s, air_c, {s: p.die0_c for s, p in self.parts.items()})
        self._replan(now_s, air_c)
        self.first_plan = self.plan
        self._command(now_s)

    def tick(self, now_s: float, air_c: float, readings: dict[int, float]) -> None:
        """One check: follow the ramp, keep the readings, re-plan when due, command."""
        self._advance_ramp(now_s)
        self._observe(now_s, air_c, readings)
        for socket in list(self.parts):
            if socket not in readings:
                del self.parts[socket]  # dropped or stable parts no longer govern
        due = now_s - self.plan_at_s >= self.cfg.replan_interval_s
        if due and self.parts and self._in_overshoot(now_s):
            self._learn()
            self._replan(now_s, air_c)
        self._command(now_s)

    def finish(self) -> None:
        """Command the target (every exit path: the chamber never stays at an overshoot)."""
        if self.commanded_c is None or abs(self.commanded_c - self.cfg.target_c) > 1e-9:
            self.chamber.set_setpoint(self.cfg.target_c)
            self.commanded_c = self.cfg.target_c

    def die_lag_now(self, socket: int) -> tuple[float, float] | None:
        """A part's die without its self-heating at its last reading, and that reading's
        time: its lag (learned) behind the air the chamber gave it (None: no readings)."""
        part = self.parts.get(socket)
        if part is None or len(part.time_s) < 2:
            return None
        t = np.asarray(part.time_s)
        air = np.interp(t, np.asarray(self.air_time_s), np.asarray(self.air_c))
        die = die_lag_c(t, air, part.die0_c - part.heat0_c, part.tau_s)
        return float(die[-1]), float(t[-1])

    def tau_of(self, socket: int) -> float:
        part = self.parts.get(socket)
        return part.tau_s if part else self.cfg.die_tau_prior_s

    def summary(self, socket: int) -> dict[str, Any]:
        """What the record keeps of the strategy for one part."""
        plan = self.first_plan
        part = self.parts.get(socket)
        return {
            "strategy": "fastest",
            "plan": "profile" if isinstance(plan, ProfilePlan) else "overshoot",
            "die_tau_s": part.tau_s if part else None,
            "overshoot_c": plan.overshoot_c if plan else 0.0,
            "hold_s": plan.hold_s if plan else 0.0,
            "predicted_settle_s": plan.settle_s if plan else None,
            "replans": self.replans,
        }

    # ------------------------------------------------------------ internals

    def _advance_ramp(self, now_s: float) -> None:
        dt = max(now_s - self.last_s, 0.0)
        self.last_s = now_s
        if self.commanded_c is None:
            return
        step = self.cfg.model.ramp_c_per_min / 60.0 * dt
        self.ramped_c += max(-step, min(step, self.commanded_c - self.ramped_c))

    def _observe(self, now_s: float, air_c: float, readings: dict[int, float]) -> None:
        self.air_time_s.append(now_s)
        self.air_c.append(air_c)
        for socket, reading in readings.items():
            part = self.parts.get(socket)
            if part is not None and math.isfinite(reading):
                part.time_s.append(now_s)
                part.reading_c.append(reading)

    def _heat_at(self, part: _Part, elapsed_s: float) -> float:
        decay = math.exp(-elapsed_s / self.cfg.heat_tau_s)
        return part.heat_final_c + (part.heat0_c - part.heat_final_c) * decay

    def _learn(self) -> None:
        """Each part's self-heating to come, then its die's lag, from its own readings."""
        air_t = np.asarray(self.air_time_s)
        air = np.asarray(self.air_c)
        t0 = air_t[0]
        for part in self.parts.values():
            t = np.asarray(part.time_s)
            if t.size < 3:
                continue
            if abs(part.heat_final_c - part.heat0_c) >= MIN_HEAT_STEP_C:
                die = die_lag_c(t, np.interp(t, air_t, air), part.die0_c - part.heat0_c,
                                part.tau_s)
                part.heat_final_c = learn_heat_final_c(
                    t - t0, np.asarray(part.reading_c) - die, part.heat0_c, part.heat_final_c,
                    self.cfg.heat_tau_s,
                )
            heat = np.array([self._heat_at(part, x - t0) for x in t])
            die = np.asarray(part.reading_c) - heat
            air_at = np.interp(t, air_t, air)
            if float(np.sum((air_at - die) ** 2)) < MIN_LEARN_C2:
                continue  # the die has not been driven enough to tell its lag
            learned = learn_die_tau_s(t, air_at, die, self.cfg.die_tau_prior_s)
            prior = self.cfg.die_tau_prior_s
            part.tau_s = min(max(learned, prior / TAU_RANGE), prior * TAU_RANGE)

    def _replan(self, now_s: float, air_c: float) -> None:
        t0 = self.air_time_s[0]
        dies = [
            DieState(
                die_c=p.reading_c[-1] if p.reading_c else p.die0_c,
                tau_s=p.tau_s,
                heat_c=self._heat_at(p, now_s - t0),
                heat_final_c=p.heat_final_c,
                heat_tau_s=self.cfg.heat_tau_s,
            )
            for p in self.parts.values()
        ]
        if not dies:
            return
        args = (
            self.cfg.model, self.cfg.limits, air_c, self.ramped_c, dies, self.cfg.target_c,
            self.cfg.criterion,
        )
        overshoot = plan_profile(*args)
        # the shaped profile, planned with a margin (the model is learned), where it is sooner;
        # the search starts where the last shaped plan would settle
        hint_s = None
        if isinstance(self.plan, ProfilePlan):
            hint_s = self.plan.settle_s - (now_s - self.plan_at_s)
        profile = plan_lp_profile(*args, not_after_s=overshoot.settle_s, hint_s=hint_s)
        self.plan = profile or overshoot
        self.plan_at_s = now_s
        self.replans += 1
        log.debug("thermal plan at %.0f s: %s", now_s, self.plan)

    def at_target_for_good(self, now_s: float) -> bool:
        """Is the plan's setpoint at the target from now on (no overshoot or profile left)?"""
        return not self._in_overshoot(now_s)

    def _in_overshoot(self, now_s: float) -> bool:
        return self.plan is not None and now_s - self.plan_at_s < self.plan.hold_s

    def _command(self, now_s: float) -> None:
        if self.plan is None:
            wanted = self.cfg.target_c
        else:
            wanted = self.plan.setpoint_at(now_s - self.plan_at_s)
        low = self.cfg.limits.setpoint_low_c
        high = self.cfg.limits.setpoint_high_c
        wanted = min(max(wanted, low), high)
        if self.commanded_c is None or abs(wanted - self.commanded_c) >= SETPOINT_RESOLUTION_C / 2:
            self.chamber.set_setpoint(wanted)
            self.commanded_c = wanted
