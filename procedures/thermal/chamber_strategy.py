"""Chamber setpoint planning for the `fastest` thermal strategy (no I/O).

A first-order model of the chamber and the die: the chamber's ramped setpoint moves towards
the commanded setpoint at its ramp limit, the air follows the ramped setpoint with `air_tau_s`,
and each die follows the air with its own lag `die_tau_s`, learned from the part's own sensor
as the run goes (`learn_die_tau_s`; the product file gives the starting value). The plan
(`plan_setpoint`) is one overshoot beyond the target held for a while, then the target: the
overshoot and the hold are searched for the soonest time the die enters its band and stays,
within the chamber's setpoint limits, a maximum overshoot and the product's maximum part
temperature. With no overshoot allowed it is the `setpoint` strategy (straight to target).
procedures/thermal/chamber_profile.py plans freer profiles (and the physics bound) on the same
model.
The stability criterion itself is unchanged and is still judged on each part's own sensor.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import maximum_filter1d, minimum_filter1d
from scipy.signal import lfilter

STEP_S = 5.0  # model time step: the air and die time constants are a minute and more


@dataclass(frozen=True)
class ThermalModel:
    """Time constants and ramp limit of the first-order chamber and die model."""

    air_tau_s: float = 60.0
    die_tau_s: float = 300.0
    ramp_c_per_min: float = 5.0


@dataclass(frozen=True)
class ThermalLimits:
    """Where the setpoint may go: the chamber's limits, the overshoot bound, the part's max."""

    setpoint_low_c: float = -40.0
    setpoint_high_c: float = 125.0
    max_overshoot_c: float = 10.0
    max_part_c: float = 125.0
    min_part_c: float = -40.0


@dataclass(frozen=True)
class ThermalState:
    """Where the chamber and the die are now (the ramped setpoint starts at the air)."""

    air_c: float
    die_c: float


@dataclass(frozen=True)
class SetpointPlan:
    target_c: float
    overshoot_c: float  # beyond the target, in the direction of travel (0: straight)
    hold_s: float  # how long the overshoot setpoint is held before the target
    settle_s: float  # predicted time from now until the die is in its band for good
    die_peak_c: float  # the die's predicted extreme (never beyond the part's limits)

    def setpoint_at(self, elapsed_s: float) -> float:
        """The setpoint to command `elapsed_s` after the plan was made."""
        return self.target_c + (self.overshoot_c if elapsed_s < self.hold_s else 0.0)


def simulate(
    model: ThermalModel,
    state: ThermalState,
    target_c: float,
    overshoot_c: NDArray[np.float64] | float,
    hold_s: NDArray[np.float64] | float,
    horizon_s: float,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(time, die temperature) predicted every STEP_S for overshoot-and-hold profiles: one
    row of die temperatures per (overshoot, hold) pair (arrays broadcast together)."""
    over, hold = np.broadcast_arrays(np.atleast_1d(overshoot_c), np.atleast_1d(hold_s))
    n = int(math.ceil(horizon_s / STEP_S)) + 1
    t = np.arange(n, dtype=np.float64) * STEP_S
    die = np.empty((over.size, n))
    air = np.full(over.size, state.air_c)
    ramped = air.copy()
    d = np.full(over.size, state.die_c)
    k_air = 1.0 - math.exp(-STEP_S / model.air_tau_s)
    k_die = 1.0 - math.exp(-STEP_S / model.die_tau_s)
    max_move = model.ramp_c_per_min / 60.0 * STEP_S
    for i in range(n):
        die[:, i] = d
        sp = target_c + np.where(t[i] < hold, over, 0.0)
        start = ramped
        ramped = ramped + np.clip(sp - ramped, -max_move, max_move)
        air_next = air + (0.5 * (start + ramped) - air) * k_air
        d = d + (0.5 * (air + air_next) - d) * k_die
        air = air_next
    return t, die


def settle_times_s(
    t: NDArray[np.float64], die: NDArray[np.float64], target_c: float, band_c: float
) -> NDArray[np.float64]:
    """Per row, the first time after which the die stays within `band_c` of the target
    (inf: not within the horizon)."""
    outside = np.abs(np.atleast_2d(die) - target_c) > band_c
    any_out = outside.any(axis=1)
    last = outside.shape[1] - 1 - np.argmax(outside[:, ::-1], axis=1)
    after = np.append(t, math.inf)[np.minimum(last + 1, t.size)]
    return np.where(any_out, after, 0.0)


def plan_setpoint(
    model: ThermalModel,
    limits: ThermalLimits,
    state: ThermalState,
    target_c: float,
    band_c: float,
    hold_step_s: float = 15.0,
    overshoot_step_c: float = 0.5,
) -> SetpointPlan:
    """The overshoot and hold that bring the die into its band soonest (a grid search over
    the model), within the setpoint limits, the overshoot bound and the part's limits; the
    straight setpoint when nothing beats it."""
    if not (model.air_tau_s > 0 and model.die_tau_s > 0 and model.ramp_c_per_min > 0):
        raise ValueError("the thermal model's time constants and ramp rate must be positive")
    if not limits.setpoint_low_c <= target_c <= limits.setpoint_high_c:
        raise ValueError(
            f"target {target_c:g} C is outside the chamber's setpoint limits "
            f"{limits.setpoint_low_c:g}..{limits.setpoint_high_c:g} C"
        )
    sign = 1.0 if target_c >= state.die_c else -1.0
    room = (limits.setpoint_high_c - target_c) if sign > 0 else (target_c - limits.setpoint_low_c)
    max_over = max(0.0, min(limits.max_overshoot_c, room))  # the die's peak is checked below
    travel_s = abs(target_c - state.air_c) / model.ramp_c_per_min * 60.0
    horizon_s = travel_s + 8.0 * model.die_tau_s + 4.0 * model.air_tau_s
    overs = np.arange(0.0, max_over + 1e-9, overshoot_step_c)
    holds = np.arange(0.0, 4.0 * model.die_tau_s + travel_s, hold_step_s)
    over_grid, hold_grid = (g.ravel() for g in np.meshgrid(sign * overs, holds))
    t, die = simulate(model, state, target_c, over_grid, hold_grid, horizon_s)
    peaks = die.max(axis=1) if sign > 0 else die.min(axis=1)
    allowed = (peaks <= limits.max_part_c) & (peaks >= limits.min_part_c)
    allowed |= (over_grid == 0.0) | (hold_grid == 0.0)  # straight to target: always allowed
    settle = np.where(allowed, settle_times_s(t, die, target_c, band_c), math.inf)
    # ties (equal settle) go to the smallest overshoot, then the shortest hold
    best = int(np.lexsort((hold_grid, np.abs(over_grid), settle))[0])
    if not math.isfinite(settle[best]) or over_grid[best] == 0.0 or hold_grid[best] == 0.0:
        straight = float(settle_times_s(t, die, target_c, band_c)[0])
        return SetpointPlan(target_c, 0.0, 0.0, straight, float(peaks[0]))
    return SetpointPlan(
        target_c, float(over_grid[best]), float(hold_grid[best]), float(settle[best]),
        float(peaks[best]),
    )


def learn_die_tau_s(
    time_s: NDArray[np.float64],
    air_c: NDArray[np.float64],
    die_c: NDArray[np.float64],
    prior_tau_s: float,
    prior_weight_c2: float = 1.0,
) -> float:
    """The die's lag behind the air from its own readings: least squares on
    d(die)/dt = (air - die) / tau, pulled towards `prior_tau_s` (the product file's value)
    with the weight of `prior_weight_c2` (C^2) of temperature difference; the prior alone
    while the die has not moved away from the air."""
    t = np.asarray(time_s, dtype=np.float64)
    if t.size < 3 or not prior_tau_s > 0:
        return prior_tau_s
    dt = np.diff(t)
    ok = dt > 0
    x = (0.5 * (air_c[1:] + air_c[:-1]) - 0.5 * (die_c[1:] + die_c[:-1]))[ok]
    y = (np.diff(die_c)[ok]) / dt[ok]
    # rate = x / tau: fit r = 1/tau, with the prior as one more weighted observation
    sxx = float(x @ x) + prior_weight_c2
    sxy = float(x @ y) + prior_weight_c2 / prior_tau_s
    if not sxy > 0:
        return prior_tau_s
    return sxx / sxy


# ---------------------------------------------------------------- several dies, self-heating

MAX_REPRESENTATIVE_DIES = 6  # the extremes govern: the slowest settles last, the fastest peaks


@dataclass(frozen=True)
class DieState:
    """One part's die as its own sensor sees it: the reading includes the self-heating, which
    moves towards `heat_final_c` (the heating at the new supply) with `heat_tau_s`."""

    die_c: float  # the sensor's reading now
    tau_s: float  # the die's lag behind the air (learned from this part's own readings)
    heat_c: float = 0.0  # the self-heating part of the reading now
    heat_final_c: float = 0.0  # the self-heating it tends to at the present supply
    heat_tau_s: float = 90.0

    def final_c(self, target_c: float) -> float:
        """Where the reading ends with the air at `target_c`."""
        return target_c + self.heat_final_c

    def heat_at(self, time_s: NDArray[np.float64]) -> NDArray[np.float64]:
        decay = np.exp(-time_s / self.heat_tau_s)
        return self.heat_final_c + (self.heat_c - self.heat_final_c) * decay


def steady_die_c(
    setpoint_c: float, supply_v: float, current_a: float, c_per_w: float | None
) -> float:
    """Where a part's die settles with the air at `setpoint_c`: the air plus its self-heating,
    the product's C/W times the power it draws (`supply_v` x `current_a`). Every thermal
    strategy ends a condition there (an overshoot is planned within the part's limits around
    it), so it is what the pre-flight checks; without a C/W only the air is known."""
    return setpoint_c + (c_per_w or 0.0) * supply_v * max(current_a, 0.0)


def _lag(x: NDArray[np.float64], k: float, y0: NDArray[np.float64] | float) -> NDArray[np.float64]:
    """y[i+1] = y[i] + (mean(x[i], x[i+1]) - y[i]) * k along the last axis, y[0] = y0: a
    first-order lag driven by a piecewise-linear input (exact for the bench's chamber step)."""
    y0_arr = np.broadcast_to(np.asarray(y0, dtype=np.float64), x.shape[:-1])
    zi = (y0_arr - 0.5 * k * x[..., 0])[..., None]
    out, _ = lfilter([0.5 * k, 0.5 * k], [1.0, -(1.0 - k)], x, axis=-1, zi=zi)
    return np.asarray(out, dtype=np.float64)


def ramped_profiles(
    model: ThermalModel,
    ramped_c: float,
    target_c: float,
    overshoot_c: NDArray[np.float64],
    hold_s: NDArray[np.float64],
    t: NDArray[np.float64],
) -> NDArray[np.float64]:
    """The chamber's ramped setpoint for each (overshoot, hold) profile at times `t`: towards
    target + overshoot at the ramp limit until the hold ends, then towards the target."""
    rate = model.ramp_c_per_min / 60.0
    o, h = overshoot_c[:, None], hold_s[:, None]
    first = target_c + o - ramped_c
    in_hold = np.minimum(t[None, :], h)
    r = ramped_c + np.sign(first) * np.minimum(rate * in_hold, np.abs(first))
    at_hold = ramped_c + np.sign(first) * np.minimum(rate * h, np.abs(first))
    second = target_c - at_hold
    after = np.maximum(t[None, :] - h, 0.0)
    moved = at_hold + np.sign(second) * np.minimum(rate * after, np.abs(second))
    return np.where(t[None, :] < h, r, moved)


@dataclass(frozen=True)
class Criterion:
    """The thermal step's stability criterion, as the model judges a predicted reading."""

    window_s: float
    slope_c_per_min: float
    band_c: float
    target_c: float | None = None  # with a tolerance: the window's mean within it
    tolerance_c: float | None = None


def settled_from_s(
    t: NDArray[np.float64], reading: NDArray[np.float64], crit: Criterion
) -> NDArray[np.float64]:
    """Per row, the end of the first window after which every window meets the stability
    criterion (slope of a straight-line fit, peak-to-peak, optional mean tolerance); windows
    start at t = 0 (the condition's start); inf when not within the horizon."""
    m = max(int(round(crit.window_s / STEP_S)), 2)
    y = np.atleast_2d(reading)
    if y.shape[-1] <= m:
        return np.full(y.shape[0], math.inf)
    win = np.lib.stride_tricks.sliding_window_view(y, m + 1, axis=-1)
    x = np.arange(m + 1) - m / 2.0
    slope = win @ (x / float(x @ x)) / STEP_S * 60.0
    # each window's peak-to-peak from running extremes (a window starts `half` before the
    # filter's centre): the same as np.ptp over the windows, without the m-fold copy
    half, n_win = (m + 1) // 2, y.shape[-1] - m
    top = maximum_filter1d(y, m + 1, axis=-1)[..., half : half + n_win]
    bottom = minimum_filter1d(y, m + 1, axis=-1)[..., half : half + n_win]
    ok = (np.abs(slope) <= crit.slope_c_per_min) & (top - bottom <= crit.band_c)
    if crit.target_c is not None and crit.tolerance_c is not None:
        ok &= np.abs(win.mean(axis=-1) - crit.target_c) <= crit.tolerance_c
    ends = t[m:]
    bad = ~ok
    any_bad = bad.any(axis=-1)
    last = bad.shape[-1] - 1 - np.argmax(bad[:, ::-1], axis=-1)
    after = np.append(ends, math.inf)[np.minimum(last + 1, ends.size)]
    return np.where(any_bad, after, ends[0])


def straight_settle_s(
    model: ThermalModel, air_c: float, die: DieState, target_c: float, crit: Criterion
) -> float:
    """Predicted station seconds from a condition's start until its stability criterion is
    met with the setpoint straight at the target (the `setpoint` strategy; `fastest` is no
    slower): the ramped setpoint moves from the air at the ramp limit, the air lags it, the
    die lags the air and its self-heating moves to the new supply's (`die.heat_final_c`).
    Used for the time left the screens show."""
    ramp = model.ramp_c_per_min if model.ramp_c_per_min > 0 else 1e6  # 0: no ramp limit
    travel_s = abs(target_c - air_c) / ramp * 60.0
    horizon_s = (
        travel_s + 8.0 * die.tau_s + 4.0 * model.air_tau_s + 8.0 * die.heat_tau_s
        + 2.0 * crit.window_s
    )
    t = np.arange(int(math.ceil(horizon_s / STEP_S)) + 1, dtype=np.float64) * STEP_S
    still = np.zeros(1)
    ramped = ramped_profiles(
        ThermalModel(model.air_tau_s, die.tau_s, ramp), air_c, target_c, still, still, t
    )
    air = _lag(ramped, 1.0 - math.exp(-STEP_S / model.air_tau_s), air_c)
    reading = _lag(air, 1.0 - math.exp(-STEP_S / die.tau_s), die.die_c - die.heat_c)
    return float(settled_from_s(t, reading + die.heat_at(t), crit)[0])


def representative_dies(dies: list[DieState], target_c: float) -> list[DieState]:
    """At most MAX_REPRESENTATIVE_DIES dies that bound the rest: the extremes of lag, of
    distance to go and of self-heating still to come."""
    if len(dies) <= MAX_REPRESENTATIVE_DIES:
        return list(dies)
    keys = (
        lambda d: d.tau_s,
        lambda d: d.final_c(target_c) - d.die_c,
        lambda d: d.heat_final_c - d.heat_c,
    )
    picked: dict[int, DieState] = {}
    for key in keys:
        ranked = sorted(range(len(dies)), key=lambda i: key(dies[i]))
        picked[ranked[0]] = dies[ranked[0]]
        picked[ranked[-1]] = dies[ranked[-1]]
    return list(picked.values())


def _direction(dies: list[DieState], target_c: float) -> float:
    worst = max(dies, key=lambda d: abs(d.final_c(target_c) - d.die_c))
    return 1.0 if worst.final_c(target_c) >= worst.die_c else -1.0


def plan_profile(
    model: ThermalModel,
    limits: ThermalLimits,
    air_c: float,
    ramped_c: float,
    dies: list[DieState],
    target_c: float,
    crit: Criterion,
    max_hold_s: float | None = None,
) -> SetpointPlan:
    """The overshoot and hold that bring the slowest of several dies (each with its own lag
    and self-heating) into its stability band soonest, no die beyond the part's limits and
    no setpoint beyond the chamber's; a coarse grid, then a fine one around its best."""
    if not dies:
        raise ValueError("no dies to plan for")
    if not (model.air_tau_s > 0 and model.ramp_c_per_min > 0 and all(d.tau_s > 0 for d in dies)):
        raise ValueError("the thermal model's time constants and ramp rate must be positive")
    if not limits.setpoint_low_c <= target_c <= limits.setpoint_high_c:
        raise ValueError(
            f"target {target_c:g} C is outside the chamber's setpoint limits "
            f"{limits.setpoint_low_c:g}..{limits.setpoint_high_c:g} C"
        )
    reps = representative_dies(dies, target_c)
    sign = _direction(reps, target_c)
    room = (limits.setpoint_high_c - target_c) if sign > 0 else (target_c - limits.setpoint_low_c)
    max_over = max(0.0, min(limits.max_overshoot_c, room))
    slowest_s = max(d.tau_s for d in reps)
    travel_s = (abs(target_c - ramped_c) + max_over) / model.ramp_c_per_min * 60.0
    horizon_s = travel_s + 5.0 * slowest_s + 4.0 * model.air_tau_s + crit.window_s
    hold_cap_s = max_hold_s if max_hold_s is not None else 3.0 * slowest_s + travel_s
    t = np.arange(int(math.ceil(horizon_s / STEP_S)) + 1, dtype=np.float64) * STEP_S

    def evaluate(overs: NDArray[np.float64], holds: NDArray[np.float64]) -> tuple[
        NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]
    ]:
        o, h = (g.ravel() for g in np.meshgrid(sign * overs, holds))
        ramped = ramped_profiles(model, ramped_c, target_c, o, h, t)
        air = _lag(ramped, 1.0 - math.exp(-STEP_S / model.air_tau_s), air_c)
        settle = np.zeros(o.size)
        hi = np.full(o.size, -math.inf)
        lo = np.full(o.size, math.inf)
        for d in reps:
            die = _lag(air, 1.0 - math.exp(-STEP_S / d.tau_s), d.die_c - d.heat_c) + d.heat_at(t)
            settle = np.maximum(settle, settled_from_s(t, die, crit))
            hi, lo = np.maximum(hi, die.max(axis=1)), np.minimum(lo, die.min(axis=1))
        ok = (hi <= limits.max_part_c) & (lo >= limits.min_part_c)
        ok |= (o == 0.0) | (h == 0.0)  # straight to target: always allowed
        peak = hi if sign > 0 else lo
        return o, h, np.where(ok, settle, math.inf), peak

    def best_of(
        o: NDArray[np.float64], h: NDArray[np.float64], s: NDArray[np.float64]
    ) -> int:
        return int(np.lexsort((h, np.abs(o), s))[0])

    o, h, s, peak = evaluate(
        np.arange(0.0, max_over + 1e-9, 1.0), np.arange(0.0, hold_cap_s + 1e-9, 30.0)
    )
    i = best_of(o, h, s)
    fine_o = np.clip(np.arange(abs(o[i]) - 1.0, abs(o[i]) + 1.0 + 1e-9, 0.25), 0.0, max_over)
    fine_h = np.clip(np.arange(h[i] - 30.0, h[i] + 30.0 + 1e-9, 5.0), 0.0, hold_cap_s)
    o2, h2, s2, peak2 = evaluate(np.unique(fine_o), np.unique(fine_h))
    j = best_of(o2, h2, s2)
    if s2[j] > s[i]:
        o2, h2, s2, peak2, j = o, h, s, peak, i
    if not math.isfinite(s2[j]) or o2[j] == 0.0 or h2[j] == 0.0:
        k = int(np.argmin(np.abs(o) + h))  # the straight profile of the coarse grid
        return SetpointPlan(target_c, 0.0, 0.0, float(s[k]), float(peak[k]))
    return SetpointPlan(target_c, float(o2[j]), float(h2[j]), float(s2[j]), float(peak2[j]))
