"""procedures/thermal/ramp_turn.py: the die's extreme after a turn, against a direct
simulation of the same chamber (ramp-limited setpoint, air lag, die lag)."""

from __future__ import annotations

import math

import pytest

from procedures.thermal.ramp_turn import (
    RampModel,
    RampState,
    extreme_after_turn,
    ramp_bound_s,
    ramped_setpoint,
)

MODEL = RampModel(ramp_c_per_min=5.0, air_tau_s=60.0, die_tau_s=300.0)


def simulate(turn_s: float, dt: float = 0.1) -> tuple[RampState, float]:
    """Heat towards 85 C from 25 C, turn towards -40 C at `turn_s`: the state at the turn
    and the die's true peak."""
    sp = air = die = 25.0
    state = None
    peak = die
    t = 0.0
    while True:
        target = 85.0 if t < turn_s else -40.0
        step = 5.0 / 60.0 * dt
        sp += max(-step, min(step, target - sp))
        air += (sp - air) * (1 - math.exp(-dt / 60.0))
        change = (air - die) * (1 - math.exp(-dt / 300.0))
        die += change
        t += dt
        if state is None and t >= turn_s:
            state = RampState(sp, air, die, change / dt)
        if t > turn_s:
            if die < peak:
                break
            peak = die
    assert state is not None
    return state, peak


@pytest.mark.parametrize("turn_s", [200.0, 400.0, 600.0])
def test_the_predicted_peak_is_the_simulated_one(turn_s: float) -> None:
    state, peak = simulate(turn_s)
    assert extreme_after_turn(state, -40.0, MODEL) == pytest.approx(peak, abs=0.15)


def test_the_trough_mirrors_the_peak() -> None:
    state, peak = simulate(400.0)
    mirrored = RampState(50 - state.setpoint_c, 50 - state.air_c, 50 - state.die_c,
                         -state.die_rate_c_per_s)
    assert extreme_after_turn(mirrored, 90.0, MODEL) == pytest.approx(50 - peak, abs=0.15)


def test_a_ramped_setpoint_moves_at_the_rate_and_stops_at_its_target() -> None:
    assert ramped_setpoint(25.0, 85.0, 5.0, 60.0) == pytest.approx(30.0)
    assert ramped_setpoint(25.0, 27.0, 5.0, 600.0) == 27.0
    assert ramped_setpoint(60.0, -40.0, 5.0, 120.0) == pytest.approx(50.0)


def test_the_ramp_bound_is_set_by_the_chamber_and_the_span() -> None:
    """The soonest a die covers the span both ways: never sooner than the air could ramp
    there and back, shorter on a faster chamber or a narrower span, longer with a slower die,
    and out of reach when the hottest setpoint allowed cannot bring the die to the top."""
    chamber = RampModel(ramp_c_per_min=5.0, air_tau_s=60.0, die_tau_s=300.0)
    limits = (-40.0, 85.0)
    base = ramp_bound_s(chamber, 25.0, 45.0, limits)
    assert base >= 2 * 20.0 / 5.0 * 60.0
    faster = RampModel(ramp_c_per_min=10.0, air_tau_s=60.0, die_tau_s=300.0)
    assert ramp_bound_s(faster, 25.0, 45.0, limits) < base
    assert ramp_bound_s(chamber, 25.0, 37.0, limits) < base
    slower_die = RampModel(ramp_c_per_min=5.0, air_tau_s=60.0, die_tau_s=600.0)
    assert ramp_bound_s(slower_die, 25.0, 45.0, limits) > base
    assert math.isinf(ramp_bound_s(chamber, 25.0, 45.0, (-40.0, 40.0)))
