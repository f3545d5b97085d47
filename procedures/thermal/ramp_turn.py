"""When to turn a temperature ramp: the die's extreme if the chamber turned now.

A die follows the chamber air through its lag (the product's `die_tau_s`), the air follows
the chamber's ramped setpoint through its own (`air_tau_s`), and the setpoint moves at the
ramp rate. A die heated by an air well above it goes on rising long after the chamber turns;
the ramp step turns the chamber when the die's predicted peak (trough) reaches the span's
end, so the dies cover the span and go little beyond it. The die's offset from the air
(self-heating, the socket's air) is taken from its own measured rate: the air it behaves as
if it saw is its temperature plus tau times its rate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class RampState:
    """The chamber and one die now (station seconds, C)."""

    setpoint_c: float  # the ramped setpoint now (where the chamber's ramp has got to)
    air_c: float
    die_c: float
    die_rate_c_per_s: float  # the die's measured rate of change


@dataclass(frozen=True)
class RampModel:
    ramp_c_per_min: float
    air_tau_s: float
    die_tau_s: float


def ramped_setpoint(start_c: float, target_c: float, ramp_c_per_min: float,
                    elapsed_s: float) -> float:
    """Where a setpoint ramping from `start_c` towards `target_c` is after `elapsed_s`."""
    step = ramp_c_per_min / 60.0 * max(elapsed_s, 0.0)
    return start_c + max(-step, min(step, target_c - start_c))


def extreme_after_turn(
    now: RampState, new_target_c: float, model: RampModel, horizon_s: float = 3600.0,
    dt_s: float = 2.0,
) -> float:
    """The die's peak (when it is rising) or trough (falling) if the setpoint turned towards
    `new_target_c` now: forward Euler of the two lags until the die turns back."""
    rising = now.die_rate_c_per_s >= 0.0
    offset = now.die_c + model.die_tau_s * now.die_rate_c_per_s - now.air_c
    sp, air, die = now.setpoint_c, now.air_c, now.die_c
    step_c = model.ramp_c_per_min / 60.0 * dt_s
    k_air = 1.0 - math.exp(-dt_s / model.air_tau_s)
    k_die = 1.0 - math.exp(-dt_s / model.die_tau_s)
    extreme = die
    for _ in range(int(horizon_s / dt_s)):
        sp += max(-step_c, min(step_c, new_target_c - sp))
        air += (sp - air) * k_air
        change = (air + offset - die) * k_die
        die += change
        if (change < 0.0) == rising:
            break
        extreme = max(extreme, die) if rising else min(extreme, die)
    return extreme


def ramp_bound_s(
    model: RampModel, bottom_c: float, top_c: float, setpoints_c: tuple[float, float],
    dt_s: float = 1.0,
) -> float:
    """The physics bound of a heating-and-cooling ramp on this chamber (station s): a die at
    rest at `bottom_c` (the air there too), the setpoint driven at the ramp rate to the
    hottest allowed setpoint, turned the moment the die's predicted peak reaches `top_c`,
    driven to the coldest, until the die is back down at `bottom_c`. No profile within the
    ramp rate and the setpoint limits covers the span both ways sooner (the turn is the latest
    that still reaches the top; the way down is at full rate). Coming to rest at the bottom
    (for what follows the ramp) is not included: it only adds."""
    low_sp, high_sp = setpoints_c
    sp = air = die = bottom_c
    k_air = 1.0 - math.exp(-dt_s / model.air_tau_s)
    k_die = 1.0 - math.exp(-dt_s / model.die_tau_s)
    step_c = model.ramp_c_per_min / 60.0 * dt_s
    target, t, rate = high_sp, 0.0, 0.0
    while t < 4 * 3600.0:
        if target == high_sp:
            peak = extreme_after_turn(RampState(sp, air, die, rate), low_sp, model, dt_s=2.0)
            target = low_sp if peak >= top_c else high_sp
        sp += max(-step_c, min(step_c, target - sp))
        air += (sp - air) * k_air
        change = (air - die) * k_die
        die, rate, t = die + change, change / dt_s, t + dt_s
        if target == low_sp and die <= bottom_c:
            return t
    return math.inf
